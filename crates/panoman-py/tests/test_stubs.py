"""The type stubs describe the native module: every stubbed name exists, and every public
name of the module is stubbed (with a docstring at run time)."""

import ast
from pathlib import Path

import panoman
from panoman import _panoman

STUB = Path(panoman.__file__).with_name("_panoman.pyi")


def stubbed():
    tree = ast.parse(STUB.read_text())
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            members = set()
            for n in node.body:
                if isinstance(n, ast.FunctionDef) and not n.name.startswith("_"):
                    members.add(n.name)
                elif isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name):
                    members.add(n.target.id)
            out[node.name] = members
        elif isinstance(node, ast.FunctionDef):
            out[node.name] = None
    return out


def test_stubs_match_module():
    assert (Path(panoman.__file__).parent / "py.typed").exists()
    stubs = stubbed()
    public = {n for n in dir(_panoman) if not n.startswith("_")}
    assert public == set(stubs), public ^ set(stubs)
    for name, members in stubs.items():
        obj = getattr(_panoman, name)
        assert obj.__doc__, name
        for m in members or ():
            assert hasattr(obj, m), f"{name}.{m}"
