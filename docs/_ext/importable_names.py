"""A local Sphinx extension: the API reference under the names users import.

loopid's packages export their public names (``loopid.control.dlqr``, defined in
``loopid.control.lqr``); the API pages document each such name once, under the package, and
each module's other names under the module. autodoc, autosummary, napoleon and viewcode do the
work; these hooks fill the gaps between them that this layout opens:

- a reference written inside a module (``:func:`dlqr```) links to the entry under the package
  (:func:`resolve_as_python_does`);
- a module's section leaves out what its package documents (:func:`once_under_the_package`);
- a constant documented under its package keeps its docstring (:func:`constant_where_defined`);
- a NamedTuple's fields are documented by name, from its ``Attributes:`` section, not as
  "Alias for field number N" (:func:`fields_by_name`);
- a constant's prose docstring is not read by napoleon as ``type: description``
  (:func:`prose_constant`);
- a ``[docs]`` link of a source page leads to the object's entry (:func:`viewcode_backlinks`).
"""

import importlib
import inspect
import re
import sys

from sphinx.util.nodes import make_refnode


def resolve_as_python_does(app, env, node, contnode):
    """A ``py`` reference that names an object through another path (``:func:`dlqr``` in
    :mod:`loopid.control.lqr`, where it is defined, while the page documents it as
    ``loopid.control.dlqr``, the name a user imports) links to where the object is documented.
    The object is found the way Python finds it (attributes first, then submodules): the name
    looked up from the referring module, its packages, the top level, then the modules of its
    own package that define it; then the object, or the class or module that holds it, is
    matched to its documented entry by identity. A name that Python finds but that has no
    documentation of its own (a constant, a private helper) stays as code text, unlinked; a name
    Python does not find is still an error."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip(".~")
    module = node.get("py:module") or ""
    parts = module.split(".") if module else []
    bases = [".".join(parts[:i]) for i in range(len(parts), 0, -1)] + [""]
    bases += _siblings_defining(module, target.split(".")[0])
    domain = env.get_domain("py")
    documented = _documented_names(app, domain)
    found_in_python = False
    for base in bases:
        dotted = (f"{base}.{target}" if base else target).split(".")
        for i in range(len(dotted), 0, -1):  # the object, else the class or module holding it
            obj = _lookup(".".join(dotted[:i]))
            if obj is _MISSING:
                continue
            found_in_python = found_in_python or i == len(dotted)
            head = documented.get(id(obj)) or ".".join(dotted[:i])
            entry = domain.objects.get(".".join([head, *dotted[i:]]))
            if entry is not None:
                return make_refnode(
                    app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, head
                )
    return contnode if found_in_python else None


_MISSING = object()


def _documented_names(app, domain) -> dict[int, str]:
    """``id(object) -> documented name`` of every documented module, class and function (by
    identity: constants are left out, since equal small values share one object). Where one
    object is documented under several names, the shortest (the package's) wins."""
    if getattr(app, "_loopid_documented", None) is None:
        names: dict[int, str] = {}
        for name, entry in sorted(domain.objects.items(), key=lambda item: -len(item[0])):
            if entry.objtype in ("module", "class", "function", "exception"):
                obj = _lookup(name)
                if obj is not _MISSING:
                    names[id(obj)] = name
        app._loopid_documented = names
    return app._loopid_documented


def _siblings_defining(module: str, name: str) -> list[str]:
    """The modules of ``module``'s package that define ``name`` themselves (a docstring naming
    a neighbour's function without its module)."""
    package = module.rpartition(".")[0]
    return [
        other
        for other, mod in sorted(sys.modules.items())
        if package
        and other.startswith(package + ".")
        and getattr(getattr(mod, name, None), "__module__", None) == other
    ]


def _lookup(dotted: str):
    """The object ``dotted`` names, as Python's ``a.b.c`` finds it: the first part imported,
    then each part an attribute, or else a submodule to import (``loopid.control.tvlqr`` is the
    function the package exports, not the module of the same name)."""
    parts = dotted.split(".")
    try:
        obj = importlib.import_module(parts[0])
    except Exception:
        return _MISSING
    for i in range(1, len(parts)):
        try:
            obj = getattr(obj, parts[i])
            continue
        except AttributeError:
            pass
        try:  # a submodule not imported yet
            obj = importlib.import_module(".".join(parts[: i + 1]))
            continue
        except Exception:
            pass
        try:  # the attribute of a module that a name of its package shadows (control.ilqr)
            obj = getattr(importlib.import_module(".".join(parts[:i])), parts[i])
        except Exception:
            return _MISSING
    return obj


def fields_by_name(app, what, name, obj, options, lines) -> None:
    """A NamedTuple's field is documented by its name and the line the class's ``Attributes:``
    section gives it, instead of Python's "Alias for field number N"; the section itself then
    leaves the class's docstring (the field's own entry replaces it). Runs before napoleon."""
    if re.fullmatch(r"Alias for field number \d+", "\n".join(lines).strip()):
        owner, _, field = name.rpartition(".")
        lines[:] = _attributes(_lookup(owner)).get(field, [])
    elif what == "class" and hasattr(obj, "_fields") and "Attributes:" in lines:
        start = lines.index("Attributes:")
        end = next(
            (i for i in range(start + 1, len(lines)) if lines[i] and not lines[i][0].isspace()),
            len(lines),
        )
        del lines[start:end]


def _attributes(cls) -> dict[str, list[str]]:
    """The fields of ``cls``'s Google-style ``Attributes:`` section: ``name: text`` lines, each
    continued by the more indented lines under it."""
    doc = inspect.cleandoc(getattr(cls, "__doc__", None) or "").splitlines()
    if "Attributes:" not in doc:
        return {}
    fields, current = {}, None
    for line in doc[doc.index("Attributes:") + 1 :]:
        if line and not line[0].isspace():
            break  # the section ends at the next unindented line
        head = re.match(r"^ {4}(\w+)(?: \([^)]*\))?:\s*(.*)$", line)
        if head:
            current = fields[head[1]] = [head[2]]
        elif current is not None:
            current.append(line.strip())
    return fields


def constant_where_defined(app, what, name, obj, options, lines) -> None:
    """A constant documented under its package's name (``loopid.systems.FUNNEL_WEIGHTS``) has
    its docstring in the module that defines it; autodoc, finding none beside the package,
    would show the docstring of the value's type (``tuple``'s). Take the defining module's."""
    if what != "data" or not inspect.isclass(type(obj)):
        return
    if "\n".join(lines).strip() != inspect.cleandoc(type(obj).__doc__ or ""):
        return
    from sphinx.pycode import ModuleAnalyzer

    package, _, short = name.rpartition(".")
    lines[:] = []
    for modname, module in sorted(sys.modules.items()):
        if modname.startswith(package + ".") and vars(module).get(short, _MISSING) is obj:
            docs = ModuleAnalyzer.for_module(modname).find_attr_docs().get(("", short))
            if docs:
                lines[:] = [line.rstrip("\n") for line in docs]
                return


def prose_constant(app, what, name, obj, options, lines) -> None:
    """A constant's or field's docstring is prose: napoleon would read a first line with a colon
    (``The readings: ...``) as ``type: description``. An empty reST comment (``..``) put first
    holds no colon, so napoleon keeps the text as it is, and the comment renders as nothing."""
    if what in ("data", "attribute", "property") and any(line.strip() for line in lines):
        lines[:0] = ["..", ""]


_documenting: list[str] = []  # the module whose members autodoc is listing now


def note_module(app, what, name, obj, options, lines) -> None:
    """Remember the module being documented (its docstring comes before its members)."""
    if what == "module":
        _documenting[:] = [name]


def once_under_the_package(app, what, name, obj, skip, options):
    """A module's member that its package exports (lists in ``__all__``) is documented once,
    under the package's name, the name a user imports (``loopid.control.dlqr``), and not again
    in the section of the module that defines it (``loopid.control.lqr``)."""
    if what != "module" or not _documenting:
        return None
    package = sys.modules.get(_documenting[0].rpartition(".")[0])
    for exported in getattr(package, "__all__", ()):
        # a name that is also a submodule's (loopid.control.ilqr) stays with its module: Sphinx
        # has one object for each full name
        if getattr(package, exported, None) is obj and not inspect.ismodule(obj):
            return None if f"{package.__name__}.{exported}" in sys.modules else True
    return None


def follow_only_loopid(app, modname, attribute):
    """The module whose source viewcode shows for ``modname.attribute``: the one that defines
    it, when that is loopid's (a constant typed ``list[...]`` says ``builtins``, which has no
    source page; viewcode would list it in its index all the same)."""
    obj = _lookup(f"{modname}.{attribute}")
    owner = getattr(obj, "__module__", None) if obj is not _MISSING else None
    return owner if isinstance(owner, str) and owner.startswith("loopid") else modname


def viewcode_backlinks(app, pagename, templatename, context, doctree) -> None:
    """viewcode links each definition of a source page back to ``<prefix>.<qualname>``, with
    one prefix for the whole module (the documented module of the first entry it saw); with
    some names documented under the package and the rest under the module, that anchor is
    wrong for one of the two. Point every back-link at the entry the object has."""
    if not pagename.startswith("_modules/") or "body" not in context:
        return
    entries = _entries_by_definition(app).get(pagename.removeprefix("_modules/").replace("/", "."))
    if not entries:
        return

    def fix(match):
        for qualname, (docname, node_id) in entries:
            if match["anchor"] == qualname or match["anchor"].endswith("." + qualname):
                uri = app.builder.get_relative_uri(pagename, docname)
                return f'class="viewcode-back" href="{uri}#{node_id}"'
        return match[0]

    context["body"] = re.sub(
        r'class="viewcode-back" href="[^"#]*#(?P<anchor>[^"]+)"', fix, context["body"]
    )


def _entries_by_definition(app) -> dict[str, list[tuple[str, tuple[str, str]]]]:
    """``defining module -> [(qualname, (docname, anchor))]`` of every documented function,
    class and method, the longest qualnames first (``Scenario.replace`` before ``replace``)."""
    if getattr(app, "_loopid_definitions", None) is None:
        found: dict[str, dict[str, tuple[str, str]]] = {}
        for name, entry in app.env.get_domain("py").objects.items():
            if entry.objtype in ("class", "function", "exception"):
                obj = _lookup(name)
                qualname = getattr(obj, "__qualname__", None)
            elif entry.objtype in ("method", "classmethod", "staticmethod", "property"):
                obj = _lookup(name.rpartition(".")[0])  # the class: a property has no module
                if not inspect.isclass(obj):
                    continue
                qualname = f"{obj.__qualname__}.{name.rpartition('.')[2]}"
            else:
                continue
            module = getattr(obj, "__module__", None)
            if isinstance(module, str) and qualname:
                found.setdefault(module, {})[qualname] = (entry.docname, entry.node_id)
        app._loopid_definitions = {
            m: sorted(q.items(), key=lambda item: -len(item[0])) for m, q in found.items()
        }
    return app._loopid_definitions


def setup(app):
    app.setup_extension("sphinx.ext.autodoc")
    app.setup_extension("sphinx.ext.napoleon")
    app.setup_extension("sphinx.ext.viewcode")
    app.connect("missing-reference", resolve_as_python_does)
    # before napoleon (priority 500), which reads the Google-style sections
    app.connect("autodoc-process-docstring", constant_where_defined, priority=300)
    app.connect("autodoc-process-docstring", fields_by_name, priority=400)
    app.connect("autodoc-process-docstring", prose_constant, priority=450)
    app.connect("autodoc-process-docstring", note_module)
    app.connect("autodoc-skip-member", once_under_the_package)
    app.connect("viewcode-follow-imported", follow_only_loopid)
    app.connect("html-page-context", viewcode_backlinks)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
