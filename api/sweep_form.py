"""The sweep form of the pages: its fields, and the request it stands for.

The form is text; ``request_from_form`` turns it into the JSON body ``POST /sweeps`` takes (the
axes from "0.3, 0.6" or "10:22:3", numbers where the text is one) and leaves every range, choice
and type check to the same request schema, so that the messages shown beside the fields are those
of the API.  Only the axis syntax is checked here (with ``sweep.grid.axis_values``, the syntax of
``airpuff sweep``).
"""

from __future__ import annotations

from typing import Any

from airpuff_core.params import (
    CHOICE_DEFAULTS,
    CHOICE_DESCRIPTIONS,
    CHOICES,
    INT_PARAMETERS,
    PARAMETERS,
    PRESET_PARAMETERS,
    SWEPT,
    ParameterError,
    choice_default_text,
)

from .html import esc

# The choices shown next to the axes (the node count and the instrument whose pulse is
# applied); the others sit with the model options.
MAIN_CHOICES = ("resolution", "instrument")
GENERAL = "_general"  # errors that belong to no single field (e.g. the grid is too large)


def unit_text(name: str) -> str:
    """The unit of a request field for labels ('' for choices, integers and dimensionless)."""
    spec = PARAMETERS.get(name)
    return spec.unit if spec is not None and spec.unit not in ("", "1") else ""


def option_names() -> list[str]:
    """The request fields besides the axes and the main choices, in the order of the form."""
    return ([n for n in CHOICES if n not in MAIN_CHOICES]
            + [n for n in PARAMETERS if n not in SWEPT] + list(INT_PARAMETERS))


def defaults() -> dict[str, str]:
    """The form's initial text: every field at its default; the fields that the ``model``
    preset sets are left empty (empty fields are left out of the request, and the preset fills
    them)."""
    values = {name: "" if name in PRESET_PARAMETERS else f"{PARAMETERS[name].default:g}"
              for name in PARAMETERS}
    values.update({name: value or "" for name, value in CHOICE_DEFAULTS.items()})
    values.update({name: str(spec[0]) for name, spec in INT_PARAMETERS.items()})
    return values


def _number_or_text(text: str, kind=float) -> Any:
    """The number written in ``text``, or the text itself for the schema to reject with its own
    message."""
    try:
        return kind(text)
    except ValueError:
        return text


def request_from_form(form: dict[str, str], max_points: int) -> tuple[dict[str, Any],
                                                                      dict[str, list[str]]]:
    """(JSON body for the request schema, axis syntax errors by field).  Empty fields are left
    out (they take their defaults, as keys missing from a POST /sweeps body do); unknown form keys
    are ignored."""
    from sweep.grid import axis_values

    body: dict[str, Any] = {}
    errors: dict[str, list[str]] = {}
    for name in SWEPT:
        text = form.get(name, "").strip()
        if not text:
            continue
        try:
            body[name] = axis_values(name, text, max_num=max_points)
        except ParameterError as err:
            errors.setdefault(name, []).append(f"{name}: {err}")
    for name in PARAMETERS:
        text = form.get(name, "").strip()
        if name not in SWEPT and text:
            body[name] = _number_or_text(text)
    for name in INT_PARAMETERS:
        text = form.get(name, "").strip()
        if text:
            body[name] = _number_or_text(text, int)
    for name in CHOICES:
        text = form.get(name, "").strip()
        if text:
            body[name] = text
    return body, errors


def _field(name: str, values: dict[str, str], errors: dict[str, list[str]], help_text: str) -> str:
    unit = unit_text(name)
    label = f"{name} [{unit}]" if unit else name
    invalid = ' class="invalid"' if name in errors else ""
    if name in CHOICES:
        options = "".join(f'<option value="{esc(c)}"{" selected" if values.get(name) == c else ""}>'
                          f"{esc(c)}</option>" for c in CHOICES[name])
        if CHOICE_DEFAULTS[name] is None:  # set by the model preset unless chosen: an empty
            # value is left out of the request, so the preset applies
            options = f'<option value="">{esc(choice_default_text(name))}</option>' + options
        control = (f'<select id="f-{esc(name)}" name="{esc(name)}"'
                   f"{invalid}>{options}</select>")
    else:
        control = (f'<input type="text" id="f-{esc(name)}" name="{esc(name)}" '
                   f'value="{esc(values.get(name, ""))}"{invalid}>')
    messages = "".join(f'<div class="field-error" id="error-{esc(name)}">{esc(m)}</div>'
                       for m in errors.get(name, ()))
    return (f'<div><label for="f-{esc(name)}">{esc(label)}</label>{control}{messages}'
            f'<div class="help">{esc(help_text)}</div></div>')


def _help(name: str) -> str:
    if name in CHOICES:
        return f"{CHOICE_DESCRIPTIONS[name]}; default {choice_default_text(name)}"
    if name in INT_PARAMETERS:
        _, lo, hi, desc = INT_PARAMETERS[name]
        return f"{desc}; an integer in [{lo}, {hi}]"
    spec = PARAMETERS[name]
    return f"{spec.description}; {spec.accepted()}"


def render(values: dict[str, str], errors: dict[str, list[str]], max_points: int) -> str:
    """The form (HTML), filled with ``values`` and showing ``errors`` beside their fields."""
    from sweep.grid import AXIS_SYNTAX

    general = "".join(f'<p class="error" id="error-{GENERAL}">{esc(m)}</p>'
                      for m in errors.get(GENERAL, ()))
    axes = "".join(_field(n, values, errors, f"{PARAMETERS[n].description}; each value "
                                             f"{PARAMETERS[n].accepted()}; {AXIS_SYNTAX}")
                   for n in SWEPT)
    main = "".join(_field(n, values, errors, _help(n)) for n in MAIN_CHOICES)
    options = "".join(_field(n, values, errors, _help(n)) for n in option_names())
    open_options = " open" if any(n in errors for n in option_names()) else ""
    return (f'<form class="sweep" method="post" action="/new" novalidate>{general}'
            f"<p class=\"muted\">The grid is the product of the four axes (at most {max_points} "
            f"points); every other value is shared by all points.</p>{axes}{main}"
            f"<details{open_options}><summary>model options (defaults of the paper's model)"
            f'</summary><div class="options">{options}</div></details>'
            f'<button type="submit" id="submit">submit sweep</button></form>')
