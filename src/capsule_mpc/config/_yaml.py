"""Reading YAML for the config: the bounded loader (duplicate keys, aliases, depth), ``base:`` merging,
validation of a section and its messages. Nothing here knows the scenario, so every section can use it."""

from __future__ import annotations

import re
import reprlib
import typing
from collections.abc import Hashable
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from ..errors import ConfigError, cut

__all__ = ["packaged_config_path", "read_yaml", "resolve_base", "validate"]

#: Longest value shown in a message, characters.
_MAX_SHOWN = 80
#: ``repr`` of a value in a message: nested containers and long strings elided with "...".
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict = 3, 8, 8, 4
_REPR.maxstring = _REPR.maxother = _MAX_SHOWN - 4


def _shown(value: Any) -> str:
    """``value``'s repr for a message, at most :data:`_MAX_SHOWN` characters."""
    return cut(_REPR.repr(value), _MAX_SHOWN)


def packaged_config_path(name: str = "paper") -> Path:
    """Path of a scenario shipped with the package (``paper``, ``rectangle``, ``pipe``)."""
    ref = resources.files("capsule_mpc") / "configs" / f"{name}.yaml"
    return Path(str(ref))


class _LoadError(yaml.YAMLError):
    """A YAML file this package refuses (a message that starts with the line)."""


#: Deepest nesting of a YAML file (a scenario nests 5 levels), most aliases, and most values
#: (scalars, lists and mappings, an alias counting what it repeats; a full scenario has ~350).
_MAX_DEPTH, _MAX_ALIASES, _MAX_VALUES = 20, 100, 10_000
_INT, _FLOAT = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"


class _ScenarioLoader(yaml.SafeLoader):
    """SafeLoader for files given to the package: bounded, strict, and reading numbers as YAML 1.2.

    * Nesting, aliases and the values they expand to are bounded (:data:`_MAX_DEPTH`,
      :data:`_MAX_ALIASES`, :data:`_MAX_VALUES`): a "billion laughs" file or a list nested
      thousands deep is refused at its line, before anything is built from it.
    * Duplicate keys are refused (PyYAML would silently keep the last value).
    * ``1e-5`` and ``-1.189e5`` are floats (strings in PyYAML's YAML 1.1); ``1:30`` is a string,
      not YAML 1.1's base-60 integer 90 (nor ``1:30.5`` a base-60 float).
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0
        #: Values (node count, an alias counting its whole node) and depth of each composed node.
        self._extent: dict[int, tuple[int, int]] = {}

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node | None:
        event = self.peek_event()
        line = event.start_mark.line + 1
        if isinstance(event, yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > _MAX_ALIASES:
                raise _LoadError(f"line {line}: more than {_MAX_ALIASES} aliases")
            node = super().compose_node(parent, index)
            if id(node) not in self._extent:
                raise _LoadError(f"line {line}: alias *{event.anchor} refers to a node that contains it")
            return node
        self._depth += 1
        if self._depth > _MAX_DEPTH:
            raise _LoadError(f"line {line}: nested deeper than {_MAX_DEPTH} levels")
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if node is None:
            return None
        children: list[yaml.Node] = []
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [item for pair in node.value for item in pair]
        extents = [self._extent[id(child)] for child in children]
        values = 1 + sum(n for n, _ in extents)
        depth = 1 + max((d for _, d in extents), default=0)
        if values > _MAX_VALUES:
            how = " (through aliases)" if self._aliases else ""
            raise _LoadError(f"line {line}: holds more than {_MAX_VALUES} values{how}")
        if depth > _MAX_DEPTH:
            raise _LoadError(f"line {line}: nested deeper than {_MAX_DEPTH} levels (through aliases)")
        self._extent[id(node)] = (values, depth)
        return node

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Hashable, Any]:
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # '<<' merges may be overridden
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.get(key)
            except TypeError:  # an unhashable key: SafeLoader reports it
                continue
            line = key_node.start_mark.line + 1
            if first is not None:
                raise _LoadError(f"line {line}: duplicate key {_shown(key)} (first given at line {first})")
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


# PyYAML's int and float resolvers without their base-60 forms, and the YAML 1.2 exponent floats.
_ScenarioLoader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag not in (_INT, _FLOAT)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_ScenarioLoader.add_implicit_resolver(
    _INT,
    re.compile(r"^(?:[-+]?0b[0-1_]+|[-+]?0[0-7_]+|[-+]?(?:0|[1-9][0-9_]*)|[-+]?0x[0-9a-fA-F_]+)$"),
    list("-+0123456789"),
)
_ScenarioLoader.add_implicit_resolver(
    _FLOAT,
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+][0-9]+)?
        |\.[0-9][0-9_]*(?:[eE][-+][0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)
_ScenarioLoader.add_implicit_resolver(
    _FLOAT,
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def read_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping that was given to the package (a scenario, a learned friction model).

    The loader (a ``yaml.SafeLoader``) bounds nesting, aliases and what they expand to, refuses
    duplicate keys, reads ``1e-5`` as a number and ``1:30`` as a string (see the module
    docstring). An empty file is an empty mapping.

    Raises
    ------
    ConfigError
        One line naming ``path`` (and the line, where there is one): the file cannot be read, is
        not UTF-8 text, not valid YAML, beyond the bounds, or not a mapping.
    """
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: not a UTF-8 text file (byte 0x{exc.object[exc.start]:02x} at offset {exc.start}); "
            "a scenario is a YAML text file"
        ) from None
    except OSError as exc:
        raise ConfigError(f"cannot read config {path}: {exc}") from exc
    try:
        data = yaml.load(text, Loader=_ScenarioLoader)  # a SafeLoader subclass: no arbitrary objects
    except _LoadError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f" line {mark.line + 1}, column {mark.column + 1}:" if mark is not None else ""
        what = " ".join(str(exc.problem or exc.context or "").split())
        raise ConfigError(f"{path}:{where} not valid YAML: {what}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a mapping, got {type(data).__name__}")
    return data


def _deep_merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def resolve_base(path: Path, data: dict[str, Any], depth: int = 0) -> dict[str, Any]:
    base = data.pop("base", None)
    if base is None:
        return data
    if not isinstance(base, str):
        raise ConfigError(f"{path}: base: must be a file name or 'paper', got {_shown(base)}")
    if depth > 8:
        raise ConfigError(f"{path}: 'base' chain deeper than 8 files (a cycle?)")
    base_path = packaged_config_path(base) if base in ("paper",) else path.parent / base
    base_data = resolve_base(base_path, read_yaml(base_path), depth + 1)
    return _deep_merge(base_data, data)


_RANGE_TEXT = {
    "greater_than": ("must be >", "gt"),
    "greater_than_equal": ("must be >=", "ge"),
    "less_than": ("must be <", "lt"),
    "less_than_equal": ("must be <=", "le"),
}


#: A number written with a unit (``"20 mm/s"``, ``"20g"``, ``"5 %"``).
_WITH_UNIT = re.compile(
    r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*[A-Za-z\u00b5\u00b0%][\w/^*. \u00b5\u00b0%-]*$"
)


def _field_description(model: Any, loc: tuple[Any, ...]) -> str | None:
    """The description of the field at ``loc`` in ``model`` (its unit and range), or None."""
    for part in loc:
        fields = getattr(model, "model_fields", None)
        if not isinstance(fields, dict) or part not in fields:
            return None
        info = fields[part]
        if part == loc[-1]:
            return info.description
        candidates = [info.annotation, *typing.get_args(info.annotation)]
        model = next((c for c in candidates if isinstance(c, type) and issubclass(c, BaseModel)), None)
    return None


def _format_errors(exc: ValidationError, where: str, model: Any = None) -> str:
    lines = []
    for err in exc.errors():
        loc = cut(".".join(str(p) for p in err["loc"]), _MAX_SHOWN) or "<top>"
        bound = _RANGE_TEXT.get(err["type"])
        if bound is not None:
            limit = err.get("ctx", {}).get(bound[1])
            shown = f"{limit:.12g}" if isinstance(limit, float) else f"{limit!s:.30}"  # an int in full
            msg = f"{bound[0]} {shown}"
        elif err["type"] == "extra_forbidden":
            msg = "unknown key (not a field of this section)"
        elif err["type"] == "missing":
            msg = "required field is missing"
        elif err["type"] == "finite_number":
            msg = "must be a finite number"
        elif err["type"] == "bool_type":
            msg = "must be true or false"
        else:
            msg = err["msg"].removeprefix("Value error, ")
        if isinstance(err.get("input"), dict):  # a rule across fields: the message names them
            lines.append(msg if loc == "<top>" else f"{loc}: {msg}")
        else:
            lines.append(f"{loc}: {msg}, got {_shown(err.get('input'))}")
            unit_typed = msg.startswith(("must be a number", "must be an integer")) and bool(
                _WITH_UNIT.match(str(err.get("input")))
            )
            about = _field_description(model, tuple(err["loc"])) if unit_typed else None
            if about:  # a unit written into the value ("20 mm/s"): say the field's unit and range
                lines[-1] += f" (write the number alone: {about})"
    return f"invalid {where}:\n  " + "\n  ".join(lines)


def validate(model: type[Any], data: dict[str, Any], where: str) -> Any:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_errors(exc, where, model)) from None
