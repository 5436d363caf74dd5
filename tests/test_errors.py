"""The package's exceptions: every error it raises on purpose derives from one base."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import capsule_mpc
from capsule_mpc.errors import CapsuleMPCError, ConfigError


def _public_exceptions() -> list[type[BaseException]]:
    found = {}
    for info in pkgutil.walk_packages(capsule_mpc.__path__, "capsule_mpc."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if (
                inspect.isclass(obj)
                and issubclass(obj, Exception)
                and not issubclass(obj, Warning)
                and obj.__module__.startswith("capsule_mpc")
                and not name.startswith("_")
            ):
                found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return list(found.values())


def test_every_public_exception_derives_from_the_base() -> None:
    classes = _public_exceptions()
    assert len(classes) >= 8  # the base, config, output, learning data, plan, and the arm's
    strays = [c.__qualname__ for c in classes if not issubclass(c, CapsuleMPCError)]
    assert strays == []


def test_exception_names_are_unique() -> None:
    names = [c.__name__ for c in _public_exceptions()]
    assert len(names) == len(set(names))


def test_config_error_is_also_a_value_error_and_bounded() -> None:
    with pytest.raises(ValueError, match=r"^x: bad$"):
        raise ConfigError("x: bad")
    long = ConfigError("\n".join(f"line {i}: " + "y" * 600 for i in range(30)))
    lines = str(long).splitlines()
    assert len(lines) == 20 and lines[-1] == "  ... and 11 more"
    assert all(len(line) <= 500 for line in lines) and lines[0].endswith("...")
