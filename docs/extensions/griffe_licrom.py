"""Griffe extensions for licrom's API reference.

:class:`SphinxRoles`: the docstrings are Google style but name other objects the Sphinx way
(:class:`FullSim`, :meth:`Model.load`, :mod:`.config`, :func:`~licrom.rigid.rigid_fit`). Each
role becomes an optional autoref to the object's canonical path: a link where the object is
rendered in the API reference, plain code where it is not (a private helper, a module without
its own page), never a broken link. Titles follow Sphinx: ``~a.b.C`` shows ``C``, anything else
as written.

:class:`ConstructorSignatures`: the classes of the native module are built by ``__new__`` (pyo3),
and their stubs say so, but griffe takes a class's signature from ``__init__`` only; without one
the class would show no parameters and its documented ``Args`` would not match. The extension
gives such a class an ``__init__`` with the parameters of its ``__new__``.
"""

from __future__ import annotations

import html
import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(class|func|meth|mod|attr|exc|data|obj):`(~?)([\w.]+)`")


def _module_of(obj: griffe.Object) -> griffe.Module:
    while not obj.is_module:
        obj = obj.parent
    return obj


def _identifier(obj: griffe.Object, role: str, target: str, collection: griffe.ModulesCollection) -> str:
    """Absolute path of ``target`` as named in the docstring of ``obj``, canonical where known."""
    if target.startswith("."):
        # Relative to the package: a package's own docstring counts from the package itself.
        module = _module_of(obj)
        base = module if module.is_init_module else module.parent
        dots = len(target) - len(target.lstrip("."))
        for _ in range(dots - 1):
            base = base.parent
        path = f"{base.path}.{target.lstrip('.')}"
    elif target.split(".")[0] in collection.members:
        path = target
    else:
        head, _, rest = target.partition(".")
        # Methods and attributes are looked up from the object outwards, everything else in its module
        # (a dataclass field may share the name of the module's function that the docstring points to).
        scope = obj if role in ("meth", "attr") else _module_of(obj)
        try:
            path = scope.resolve(head)
        except griffe.NameResolutionError:
            path = f"{_module_of(obj).path}.{head}"
        if rest:
            path = f"{path}.{rest}"
    try:
        found = collection[path]
        return found.canonical_path
    except (KeyError, griffe.AliasResolutionError, griffe.CyclicAliasError):
        return path


class SphinxRoles(griffe.Extension):
    """Rewrite ``:role:`target``` in every docstring as an optional autoref."""

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        self._walk(pkg, loader.modules_collection, set())

    def _walk(self, obj: griffe.Object, collection: griffe.ModulesCollection, seen: set[str]) -> None:
        if obj.path in seen:
            return
        seen.add(obj.path)
        if obj.docstring is not None and ":" in obj.docstring.value:
            obj.docstring.value = _ROLE.sub(lambda m: self._ref(obj, m, collection), obj.docstring.value)
        for member in obj.members.values():
            if not member.is_alias:
                self._walk(member, collection, seen)

    @staticmethod
    def _ref(obj: griffe.Object, match: re.Match[str], collection: griffe.ModulesCollection) -> str:
        role, short, target = match.group(1), match.group(2), match.group(3)
        title = target.rsplit(".", 1)[-1] if short else target
        identifier = _identifier(obj, role, target, collection)
        return f'<autoref identifier="{html.escape(identifier)}" optional><code>{html.escape(title)}</code></autoref>'


class ConstructorSignatures(griffe.Extension):
    """Give a class built by ``__new__`` alone an ``__init__`` with the same parameters."""

    def on_class(self, *, cls: griffe.Class, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        new = cls.members.get("__new__")
        if new is None or new.is_alias or "__init__" in cls.members or not isinstance(new, griffe.Function):
            return
        params = list(new.parameters)[1:]  # without cls
        init = griffe.Function(
            "__init__",
            lineno=new.lineno,
            endlineno=new.endlineno,
            parameters=griffe.Parameters(griffe.Parameter("self", kind=griffe.ParameterKind.positional_or_keyword), *params),
            returns="None",
        )
        cls.set_member("__init__", init)
