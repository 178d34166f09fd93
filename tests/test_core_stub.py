"""python/pano4d/_core.pyi against the built extension: the same public names at module level
and in each class, and the same arguments (names, keyword-only or not, defaulted or not) for
every function, constructor and method the extension reports a signature for."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path
from typing import Any

import pytest

from pano4d import extension

STUB = Path(extension.__file__).with_name("_core.pyi")

# (name, keyword-only, has a default) per argument, self left out.
Arguments = list[tuple[str, bool, bool]]


def _public(name: str) -> bool:
    return not name.startswith("_") or name == "__version__"


def _stub_arguments(fn: ast.FunctionDef) -> Arguments:
    a = fn.args
    positional = [*a.posonlyargs, *a.args]
    defaulted = len(positional) - len(a.defaults)
    out = [(p.arg, False, i >= defaulted) for i, p in enumerate(positional)]
    out += [(p.arg, True, d is not None) for p, d in zip(a.kwonlyargs, a.kw_defaults, strict=True)]
    return [x for x in out if x[0] != "self"]


def _runtime_arguments(obj: Any) -> Arguments | None:
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):
        return None  # getters and slots report none
    return [
        (p.name, p.kind is p.KEYWORD_ONLY, p.default is not p.empty)
        for p in signature.parameters.values()
        if p.name != "self"
    ]


def _stub() -> dict[str, ast.AST]:
    tree = ast.parse(STUB.read_text())
    names: dict[str, ast.AST] = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.ClassDef):
            names[node.name] = node
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names[node.target.id] = node
    return {k: v for k, v in names.items() if _public(k)}


def _methods(cls: ast.ClassDef) -> dict[str, ast.FunctionDef]:
    return {n.name: n for n in cls.body if isinstance(n, ast.FunctionDef)}


@pytest.fixture(scope="module")
def core() -> Any:
    pytest.importorskip("pano4d._core")
    from pano4d import _core

    return _core


def test_the_stub_names_what_the_module_has(core: Any) -> None:
    stub = _stub()
    built = {name for name in dir(core) if _public(name)}
    assert sorted(built - set(stub)) == [], "in the extension, missing from _core.pyi"
    assert sorted(set(stub) - built) == [], "in _core.pyi, not in the extension"


def test_every_class_and_function_takes_what_the_stub_says(core: Any) -> None:
    mismatches = []
    for name, node in _stub().items():
        obj = getattr(core, name)
        if isinstance(node, ast.FunctionDef) and _runtime_arguments(obj) != _stub_arguments(node):
            mismatches.append((name, _runtime_arguments(obj), _stub_arguments(node)))
        if not isinstance(node, ast.ClassDef):
            continue
        stubbed = _methods(node)
        built = {m for m in vars(obj) if _public(m)} | ({"__len__"} & set(vars(obj)))
        declared = {m for m in stubbed if _public(m) or m == "__len__"}
        if built != declared:
            mismatches.append((name, sorted(built - declared), sorted(declared - built)))
        if "__init__" in stubbed:
            got = _runtime_arguments(obj)
            if got != _stub_arguments(stubbed["__init__"]):
                mismatches.append((f"{name}()", got, _stub_arguments(stubbed["__init__"])))
        for method, fn in stubbed.items():
            if method.startswith("_") or method not in vars(obj):
                continue
            got = _runtime_arguments(getattr(obj, method))
            if got is not None and got != _stub_arguments(fn):
                mismatches.append((f"{name}.{method}", got, _stub_arguments(fn)))
    assert mismatches == []
