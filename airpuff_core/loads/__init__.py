"""The loads on the cornea from outside: the air jet of eq. (11) (``air_jet.py``)."""
