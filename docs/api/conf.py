"""Sphinx configuration of the API reference (``make docs``: build/docs/index.html).

The reference is autodoc's rendering of the docstrings, and the build is their check: nitpicky
mode makes every cross-reference (``:class:``, ``:func:``, ``:meth:``, a type hint) that names
nothing a warning, and ``make docs`` runs ``sphinx-build -W --keep-going``, so each one fails the
build (tests/test_docs.py runs the same build under ``make test``). Without internet there is no
intersphinx: references into other libraries (numpy, scipy, pydrake, …) and into the standard
library are ignored by name below, and nothing of ``dualarm_mpc`` is.

Each public name (``dualarm_mpc.__all__``) is documented once, at the top (index.rst), as
``dualarm_mpc.NAME``; its module's section leaves it out, and a reference to it by the module it
is defined in (``dualarm_mpc.model.mld.State``) leads to the top: classes by autodoc's
``:canonical:``, functions and members by ``public_by_module`` below. Drake's
``.. pydrake_system::`` (a LeafSystem's ports) is drawn by ``PydrakeSystem``; ``|u|`` stays an
absolute value (``AbsoluteValues``). Every module of the package but the command line's and the
scenarios' must be on a page, and every public name at the top (``check_coverage``).
"""

from __future__ import annotations

import dataclasses
import pkgutil
import sys
from pathlib import Path

import yaml
from docutils import nodes
from sphinx import addnodes
from sphinx.transforms import SphinxTransform
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # the source tree's package, installed or not

import dualarm_mpc  # noqa: E402

project = "dualarm_mpc"
release = version = dualarm_mpc.__version__
extensions = ["sphinx.ext.autodoc"]
exclude_patterns = []
html_theme = "alabaster"
html_static_path = []

autodoc_default_options = {"members": True, "member-order": "bysource"}
autodoc_typehints = "signature"
autoclass_content = "both"  # the class's docstring, then __init__'s where it has one
nitpicky = True

# What a build without intersphinx cannot resolve, and only that: other libraries' names and the
# standard library's. A name of dualarm_mpc is never here.
_EXTERNAL = ("numpy", "scipy", "pydrake", "highspy", "matplotlib", "yaml", "ortools", "gurobipy",
             "cplex", "pyscipopt", "dask", "distributed")
_STDLIB = ("pathlib", "collections", "argparse", "concurrent", "dataclasses",
           "enum", "io", "logging", "multiprocessing", "subprocess", "threading", "types",
           "typing", "os", "re", "json", "contextlib", "fractions", "random", "signal",
           "queue", "datetime", "functools", "itertools", "weakref", "abc", "numbers")
_PREFIXES = "|".join(name.replace(".", r"\.") for name in _EXTERNAL + _STDLIB)
nitpick_ignore_regex = [(r"py:.*", rf"({_PREFIXES})\..+")]

logger = logging.getLogger(__name__)

# Subpackages the reference leaves out: the command line (docs/cli.md) and the built-in scenarios
# (YAML files; docs/scenarios.md).
_UNDOCUMENTED = ("cli", "scenarios")


def _public() -> dict[str, str]:
    """``module.NAME`` → ``dualarm_mpc.NAME``, for every public name (``_EXPORTS``)."""
    return {f"{module}.{name}": f"dualarm_mpc.{name}"
            for name, module in dualarm_mpc._EXPORTS.items()}


def skip_public(app, what, name, obj, skip, options):
    """Leave a public name out of its module's section: it is documented at the top."""
    if what == "module" and f"{getattr(obj, '__module__', None)}.{name}" in _public():
        return True
    return None


def _enclosing_public(node) -> str | None:
    """The public name whose entry at the top (index.rst) ``node`` is in, if any."""
    name = None
    parent = node.parent
    while parent is not None:  # the outermost entry wins: a method's class
        if isinstance(parent, addnodes.desc):
            for sig in parent.findall(addnodes.desc_signature):
                if sig.get("module") == "dualarm_mpc":
                    name = sig.get("fullname", "").split(".")[0]
                break
        parent = parent.parent
    return name if name in dualarm_mpc._EXPORTS else None


def public_by_module(app, env, node, contnode):
    """References that the public names' move to the top would break, resolved as in the module
    that defines the name:

    * a public name, or a member of one, by its module (``dualarm_mpc.logic.parser.parse``,
      ``dualarm_mpc.model.mld.State.vector``, or ``knock`` within its own module) → its entry at
      the top (``dualarm_mpc.parse``, ``dualarm_mpc.State.vector``, ``dualarm_mpc.knock``);
      autodoc's ``:canonical:`` does this for a class itself, not for its members nor for
      functions;
    * a short reference in a public name's own docstring, which is read at the top but written
      in its module (``check_events`` in the docstring of ``simulate``) → that module's.

    Whatever resolves nowhere stays a warning."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip("~.")
    candidates = [target]
    if node.get("py:module"):
        candidates.append(f"{node['py:module']}.{target}")
    owner = _enclosing_public(node)
    if owner is not None:
        candidates.append(f"{dualarm_mpc._EXPORTS[owner]}.{target}")
    domain = env.get_domain("py")
    for name in candidates:
        top = next((top + name.removeprefix(canonical) for canonical, top in _public().items()
                    if name == canonical or name.startswith(canonical + ".")), None)
        if top is None and name == target:
            continue  # as written: Sphinx found nothing there
        found = domain.resolve_xref(env, node["refdoc"], app.builder, node["reftype"],
                                    top or name, node, contnode)
        if found is not None:
            return found
    return None


def dataclass_factories(app, what, name, obj, options, signature, return_annotation):
    """A dataclass field's ``default_factory`` shown as the call that makes the default
    (``dict()``, ``Robot()``; ``...`` for a lambda) instead of ``<factory>``, which is no Python
    and would make Sphinx parse the signature by commas, splitting ``dict[str, list[float]]``."""
    if not signature or "<factory>" not in signature or not dataclasses.is_dataclass(obj):
        return None
    for f in dataclasses.fields(obj):
        if f.init and f.default_factory is not dataclasses.MISSING:
            made = getattr(f.default_factory, "__name__", "<lambda>")
            signature = signature.replace("<factory>", "..." if made == "<lambda>"
                                          else f"{made}()", 1)
    return signature, return_annotation


def private_in_signature(app, env, node, contnode):
    """A private class in a signature's type hint (``dualarm_mpc.model.route._Grab``, from the
    alias ``Visit`` that autodoc expands) is shown as written, unlinked: it is in no page. A
    docstring's reference to a private name is still an error (write ``:func:`!_name```)."""
    if node.get("refdomain") != "py" or not any(
            part.startswith("_") and not part.startswith("__")
            for part in node["reftarget"].split(".")):
        return None
    parent = node.parent
    while parent is not None and not isinstance(parent, addnodes.desc_signature):
        parent = parent.parent
    return contnode if parent is not None else None


class AbsoluteValues(SphinxTransform):
    """``|u|`` in a docstring is an absolute value (or a norm), as in the paper, never a reST
    substitution (the docstrings define none): each reference to a substitution that is not
    defined is put back as the text it was written as, before docutils' own transform (priority
    220) would report it. Sphinx's own (``|version|``, ``|release|``, ``|today|``) are kept."""

    default_priority = 200

    def apply(self, **kwargs):
        keep = {"version", "release", "today", "translation progress"}
        for ref in list(self.document.findall(nodes.substitution_reference)):
            name = ref["refname"]
            if name in keep or name in self.document.substitution_names:
                continue
            ref.replace_self(nodes.Text(f"|{ref.astext()}|"))


class PydrakeSystem(SphinxDirective):
    """Drake's ``.. pydrake_system::`` (its docs' own extension, not pydrake's package): a
    LeafSystem's name and ports, as YAML, drawn as a block with its inputs on the left and its
    outputs on the right."""

    has_content = True

    def run(self):
        spec = yaml.safe_load("\n".join(self.content))
        inputs = spec.get("input_ports") or []
        outputs = spec.get("output_ports") or []
        name = spec["name"]
        rows = max(len(inputs), len(outputs), 1)
        left = max((len(p) for p in inputs), default=0)
        inner = len(name) + 2
        lines = [" " * (left + 2) + "┌" + "─" * inner + "┐"]
        for k in range(rows):
            port = inputs[k] if k < len(inputs) else ""
            label = name if k == 0 else ""
            out = outputs[k] if k < len(outputs) else ""
            lines.append(f"{port:>{left}} {'→' if port else ' '}│{label:^{inner}}│"
                         f"{'→ ' + out if out else ''}")
        lines.append(" " * (left + 2) + "└" + "─" * inner + "┘")
        text = "\n".join(lines)
        return [nodes.literal_block(text, text)]


def check_coverage(app, env):
    """A warning (an error under -W) for each module of the package that no page documents, and
    each public name not documented at the top: a new module or export cannot be left out."""
    documented = set(env.get_domain("py").modules)
    for info in pkgutil.walk_packages(dualarm_mpc.__path__, "dualarm_mpc."):
        name = info.name
        if name.split(".")[1] in _UNDOCUMENTED:
            continue
        if name not in documented:
            logger.warning("module %s is in no page of docs/api", name)
    objects = env.get_domain("py").objects
    for name in dualarm_mpc.__all__:
        if f"dualarm_mpc.{name}" not in objects:
            logger.warning("public name dualarm_mpc.%s is not documented in docs/api/index.rst",
                           name)


def setup(app):
    app.connect("autodoc-skip-member", skip_public)
    app.connect("autodoc-process-signature", dataclass_factories)
    app.connect("missing-reference", public_by_module)
    app.connect("missing-reference", private_in_signature)
    app.connect("env-check-consistency", check_coverage)
    app.add_directive("pydrake_system", PydrakeSystem)
    app.add_transform(AbsoluteValues)
    return {"parallel_read_safe": True}

