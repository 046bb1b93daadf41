"""A Markdown reference of config dataclasses: every key with its type, default and one line of help.

The help of a field is, in this order: ``metadata["help"]``; its entry in the class docstring's ``Attributes:``
section; the comment on its line or the comment lines right above it. The first sentence is kept. Fields marked
``set_by`` (copies of a setting kept elsewhere, see :func:`gof_warp.core.config.to_dict`) are left out.
"""

from __future__ import annotations

import dataclasses
import inspect
import io
import re
import textwrap
import tokenize
import typing

_ATTR = re.compile(r"^(\w+)(?: \([^)]*\))?: ?(.*)$")


def _first_sentence(text: str) -> str:
    text = " ".join(text.split())
    m = re.search(r"(?<=[^.][.])\s(?=[A-Z(`\"'])", text)
    return (text[:m.start()] if m else text).strip()


def _docstring_help(cls) -> dict[str, str]:
    doc = inspect.getdoc(cls) or ""
    out: dict[str, str] = {}
    lines = doc.splitlines()
    try:
        start = next(i for i, ln in enumerate(lines) if ln.strip() == "Attributes:")
    except StopIteration:
        return out
    key = None
    for ln in lines[start + 1:]:
        if ln and not ln.startswith(" "):
            break
        stripped = ln.strip()
        indent = len(ln) - len(ln.lstrip())
        m = _ATTR.match(stripped)
        if m and indent <= 4:
            key = m.group(1)
            out[key] = m.group(2)
        elif key and stripped:
            out[key] += " " + stripped
    return out


def _comment_help(cls) -> dict[str, str]:
    try:
        src = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    comments: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
    lines = src.splitlines()
    out: dict[str, str] = {}
    for no, ln in enumerate(lines, 1):
        m = re.match(r"^    (\w+): ", ln)
        if not m:
            continue
        name = m.group(1)
        if no in comments and not ln.lstrip().startswith("#"):
            out[name] = comments[no]
            continue
        above, k = [], no - 1
        while k >= 1 and lines[k - 1].lstrip().startswith("#"):
            above.insert(0, comments.get(k, ""))
            k -= 1
        if above:
            out[name] = " ".join(above)
    return out


def field_help(cls) -> dict[str, str]:
    """``{field name: one line of help}`` for dataclass ``cls`` (module docstring: where the help comes from)."""
    merged = {**_comment_help(cls), **_docstring_help(cls)}
    out = {}
    for f in dataclasses.fields(cls):
        text = f.metadata.get("help") or merged.get(f.name, "")
        out[f.name] = _first_sentence(text)
    return out


def _type_name(annotation) -> str:
    text = annotation.__name__ if isinstance(annotation, type) else str(annotation)
    return text.replace("typing.", "").replace("NoneType", "None")


def _default(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return ""
    if isinstance(value, float):
        return repr(round(value, 6)) if value == round(value, 6) else f"{value:.6g}"
    if isinstance(value, tuple):
        return "[" + ", ".join(str(_default_value(v)) for v in value) + "]"
    if isinstance(value, str):
        return value
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _default_value(v):
    return repr(v) if isinstance(v, float) else v


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _rows(cls, prefix: str) -> tuple[list[str], list[tuple[str, type]]]:
    hints = typing.get_type_hints(cls)
    helps = field_help(cls)
    rows, nested = [], []
    for f in dataclasses.fields(cls):
        if f.metadata.get("set_by"):
            continue
        t = hints[f.name]
        if dataclasses.is_dataclass(t):
            nested.append((prefix + f.name, t))
            continue
        rows.append(f"| `{prefix}{f.name}` | `{_cell(_type_name(t))}` | `{_cell(_default(f))}` | "
                    f"{_cell(helps[f.name])} |")
    return rows, nested


def _section(title: str, cls, prefix: str, level: int) -> list[str]:
    rows, nested = _rows(cls, prefix)
    doc = _first_sentence((inspect.getdoc(cls) or "").split("\n\n")[0])
    out = [f"{'#' * level} {title}", ""]
    if doc:
        out += [doc, ""]
    if rows:
        out += ["| key | type | default | meaning |", "| --- | --- | --- | --- |", *rows, ""]
    for name, sub in nested:
        out += _section(f"`{name}`", sub, name + ".", level + 1)
    return out


def render_config_reference(parts: list[tuple[str, type, str]], header: str = "") -> str:
    """Markdown for ``parts``: ``(title, dataclass, key prefix)`` each, its nested dataclasses as subsections
    (in field order: put an ``experimental`` section last in the dataclass to have it last here)."""
    out = [header.rstrip(), ""] if header else []
    for title, cls, prefix in parts:
        out += _section(title, cls, prefix, 2)
    return "\n".join(out).rstrip() + "\n"
