"""The cornea: its models behind one interface, chosen by name, and its tissue law.

- ``registry.py``: the models' names (the choices of ``cornea``) and the options each reads;
- ``interface.py``: ``CorneaModel``, what every model implements;
- ``reference.py``: the prestressed reference and the discrete membrane all models build on,
  and the static equilibrium; ``apex.py``: the apex curvature;
- ``membrane.py``, ``kirchhoff.py``, ``mindlin.py``: one module per model;
- ``build.py``: ``cornea_for_run``, the model of a run by its name;
- ``tissue.py``: the tissue law (elastic or viscoelastic) applied to any model's resultants.

This package's ``__init__`` imports nothing: the parameter table reads ``registry`` without
loading the kernels.
"""
