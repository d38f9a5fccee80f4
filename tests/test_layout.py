"""The layering rules of ``ident`` and ``planner``, checked by walking every module's AST.

Like python-control's test that walks every public function, this test reads
the source of every module of the packages (nothing is imported except in the
one subprocess check) and enforces, one test per rule:

- no private name (a leading underscore, ``_CONSTANTS`` included, dunders not)
  imported across modules: ``from m import _x``, and ``import m`` /
  ``import m as a`` / ``from p import m`` followed by ``m._x`` / ``a._x``. A
  module may use its own privates; a package ``__init__`` may re-export only
  public names. A private *module* (``_kernels.py``) may be imported only from
  inside its own package;
- no import cycle between first-party modules (the graph holds every
  first-party import, in function bodies and ``TYPE_CHECKING`` blocks too);
- first-party imports at module top (module level, including inside a
  top-level ``if``/``try``); function-body imports only in
  :data:`BODY_IMPORT_MODULES` (the command line's package and the demo);
- no heavy optional library (:data:`HEAVY`) imported at module top by
  :data:`CLI` or by any module it imports at module top, so that
  ``shockplan --help`` stays fast; and a subprocess confirms that importing
  the CLI and running ``--help`` loads none of them (no timing: the modules
  loaded are checked, not the seconds);
- ``ident`` never imports ``planner`` (anywhere, function bodies included);
- no relative imports;
- no module over :data:`MAX_LINES` lines except compiled-kernel modules: a
  module is a kernel module when more than half of its lines lie in
  module-level functions decorated with a numba compiler (:data:`NUMBA_DECORATORS`,
  as ``@numba.njit``, ``@nb.njit(...)``, ``@njit`` ...; from the first
  decorator line to the function's last line);
- no public function or method (numba kernels included) with more than
  :data:`MAX_PARAMETERS` parameters (positional, keyword-only, ``*args`` and
  ``**kwargs`` each count one; a method's ``self``/``cls`` does not); private
  names (a leading underscore) and functions nested in functions are exempt: group
  the options of a concept in one keyword-only object (:mod:`planner.options`).

Every checker takes the scanned tree as an argument, and the self-tests at the
end feed each one a small synthetic package in ``tmp_path`` with one violation
(and the allowed forms next to it), so every rule is shown able to fail.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("ident", "planner")
#: Modules allowed to import first-party modules inside function bodies: a name, or
#: ``"pkg.*"`` for every module under the package ``pkg`` (the command line's package: its
#: command modules import the library when a command runs).
BODY_IMPORT_MODULES = frozenset({"planner.cli", "planner.cli.*", "planner.demo"})
#: The command line (a package: its ``__init__`` imports every command module), whose
#: module-top import closure must stay light.
CLI = "planner.cli"
#: Heavy optional libraries, imported only where used (never on the CLI's start-up path).
HEAVY = ("casadi", "cvxpy", "distributed", "dask", "matplotlib", "openpyxl")
#: The lower layer never imports the upper one.
LOWER, UPPER = "ident", "planner"
MAX_LINES = 1500
#: Parameters a public function or method may take at most.
MAX_PARAMETERS = 16
#: numba's compiling decorators; a function decorated with one of these is compiled code.
NUMBA_DECORATORS = frozenset({"jit", "njit", "vectorize", "guvectorize", "cfunc",
                              "generated_jit", "stencil"})


# ----------------------------------------------------------------------------------------------
# the scan
# ----------------------------------------------------------------------------------------------

@dataclass
class Import:
    """One import of a module: ``target`` is the module imported, ``name`` the attribute taken
    from it (``None`` when a module itself is bound, ``"*"`` for a star import)."""

    module: str
    lineno: int
    target: str
    name: str | None
    top: bool               # at module level (not inside a def, lambda or class body)
    scope: str              # "" at module level, else the enclosing def/class
    relative: bool
    type_checking: bool     # inside ``if TYPE_CHECKING:``
    text: str               # the import as written, for messages


@dataclass
class Module:
    name: str
    path: Path
    rel: str                # path relative to the scanned root, for messages
    is_package: bool
    source: str
    tree: ast.Module
    imports: list[Import] = field(default_factory=list)
    bindings: dict[str, str] = field(default_factory=dict)   # local name -> first-party module


@dataclass
class Project:
    root: Path
    packages: tuple[str, ...]
    modules: dict[str, Module]

    def first_party(self, dotted):
        return dotted.split(".")[0] in self.packages


def _module_name(path, root):
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _is_private(name):
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _is_type_checking(test):
    return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
            or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def _resolve_relative(mod, level, name):
    """The absolute module a ``from .x import y`` of `mod` names."""
    parts = mod.name.split(".")
    base = parts if mod.is_package else parts[:-1]
    base = base[:len(base) - (level - 1)] if level > 1 else base
    return ".".join(base + ([name] if name else []))


def _collect_imports(mod, project):
    """Every import statement (and constant-string ``import_module``/``__import__`` call)."""

    def add(node, target, name, scope, tc, relative=False):
        text = " ".join((ast.get_source_segment(mod.source, node) or target).split())
        mod.imports.append(Import(mod.name, node.lineno, target, name, not scope, scope,
                                  relative, tc, text))

    def visit(node, scope, tc):
        if isinstance(node, ast.Import):
            for a in node.names:
                bound = a.asname or a.name.split(".")[0]
                add(node, a.name, None, scope, tc)
                if project.first_party(a.name):
                    mod.bindings[bound] = a.name if a.asname else a.name.split(".")[0]
            return
        if isinstance(node, ast.ImportFrom):
            relative = node.level > 0
            base = (_resolve_relative(mod, node.level, node.module) if relative
                    else node.module)
            for a in node.names:
                sub = f"{base}.{a.name}"
                if a.name != "*" and sub in project.modules:
                    add(node, sub, None, scope, tc, relative=relative)
                    if project.first_party(sub):
                        mod.bindings[a.asname or a.name] = sub
                else:
                    add(node, base, a.name, scope, tc, relative=relative)
            return
        if (isinstance(node, ast.Call) and node.args
                and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)
                and ((isinstance(node.func, ast.Attribute) and node.func.attr == "import_module")
                     or (isinstance(node.func, ast.Name)
                         and node.func.id in ("import_module", "__import__")))):
            add(node, node.args[0].value, None, scope or "<dynamic>", tc)
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            for d in getattr(node, "decorator_list", []):
                visit(d, scope, tc)
            inner = f"{scope}.{node.name}" if scope else node.name
            for child in node.body:
                visit(child, inner, tc)
            return
        if isinstance(node, ast.Lambda):
            visit(node.body, scope or "<lambda>", tc)
            return
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.body:
                visit(child, scope, True)
            for child in node.orelse:
                visit(child, scope, tc)
            return
        for child in ast.iter_child_nodes(node):
            visit(child, scope, tc)

    for stmt in mod.tree.body:
        visit(stmt, "", False)


def scan(root, packages):
    """Parse every module of `packages` under `root` (a folder holding the packages)."""
    root = Path(root)
    modules = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            source = path.read_text(encoding="utf-8")
            name = _module_name(path, root)
            modules[name] = Module(name, path, path.relative_to(root).as_posix(),
                                   path.name == "__init__.py", source,
                                   ast.parse(source, filename=str(path)))
    project = Project(root, tuple(packages), modules)
    for mod in modules.values():
        _collect_imports(mod, project)
    return project


def _where(mod, imp):
    scope = f" (in {imp.scope})" if imp.scope else ""
    return f"{mod.rel}:{imp.lineno}: {imp.text}{scope}"


def _message(what, offenders, fix):
    return (f"{len(offenders)} {what}; {fix}:\n  " + "\n  ".join(offenders))


# ----------------------------------------------------------------------------------------------
# the checkers: each returns the offenders, one line each, "file:line: what"
# ----------------------------------------------------------------------------------------------

def _private_module_offence(importer, dotted):
    """A private component of a module path imported from outside its package."""
    parts = dotted.split(".")
    for i, part in enumerate(parts):
        if _is_private(part):
            owner = ".".join(parts[:i])
            if importer != owner and not importer.startswith(owner + "."):
                return ".".join(parts[:i + 1])
    return None


def private_imports(project):
    """Private names taken from another first-party module, by import or attribute access."""
    out = []
    for mod in project.modules.values():
        for imp in mod.imports:
            if not project.first_party(imp.target):
                continue
            scope = f" (in {imp.scope})" if imp.scope else ""
            bad = _private_module_offence(mod.name, imp.target)
            if bad:
                out.append(f"{mod.rel}:{imp.lineno}: {imp.target}{scope}  [private module {bad}]")
            elif (imp.name and imp.name != "*" and _is_private(imp.name)
                  and imp.target != mod.name):
                out.append(f"{mod.rel}:{imp.lineno}: {imp.target}.{imp.name}{scope}")
        if not mod.bindings:
            continue
        for node in ast.walk(mod.tree):
            if not isinstance(node, ast.Attribute):
                continue
            chain, base = [], node
            while isinstance(base, ast.Attribute):
                chain.append(base.attr)
                base = base.value
            if not isinstance(base, ast.Name) or base.id not in mod.bindings:
                continue
            chain.reverse()
            current = mod.bindings[base.id]
            for i, attr in enumerate(chain):
                if f"{current}.{attr}" in project.modules:
                    current = f"{current}.{attr}"
                    bad = _private_module_offence(mod.name, current)
                    if bad == current and i == len(chain) - 1:
                        out.append(f"{mod.rel}:{node.lineno}: {current} (as "
                                   f"{ast.unparse(node)})  [private module {bad}]")
                    continue
                # attr is the first non-module attribute: report it once, at its own node
                if (i == len(chain) - 1 and _is_private(attr) and current != mod.name):
                    out.append(f"{mod.rel}:{node.lineno}: {current}.{attr} (as "
                               f"{ast.unparse(node)})")
                break
    return sorted(set(out), key=_by_place)


def _by_place(line):
    """Sort key of an offender line: file, then line number."""
    rel, lineno = line.split(":")[:2]
    return rel, int(lineno)


def _module_edges(project, *, top_only=False, runtime_only=False):
    """{module: {imported first-party module: [Import, ...]}} over the scanned modules."""
    edges = {name: {} for name in project.modules}
    for mod in project.modules.values():
        for imp in mod.imports:
            if top_only and not imp.top:
                continue
            if runtime_only and imp.type_checking:
                continue
            if imp.target in project.modules and imp.target != mod.name:
                edges[mod.name].setdefault(imp.target, []).append(imp)
    return edges


def _strongly_connected(graph):
    """Tarjan's strongly connected components of {node: iterable of nodes}."""
    index, low, on_stack, stack, comps = {}, {}, set(), [], []
    counter = [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            comps.append(sorted(comp))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph) + 100))
    try:
        for v in sorted(graph):
            if v not in index:
                strong(v)
    finally:
        sys.setrecursionlimit(limit)
    return comps


def _shortest_cycle(graph, start, members):
    """A shortest cycle through `start` inside `members` (BFS), as a list of nodes."""
    prev = {start: None}
    queue = deque([start])
    while queue:
        v = queue.popleft()
        for w in sorted(graph[v]):
            if w not in members:
                continue
            if w == start:
                path = [v]
                while prev[path[-1]] is not None:
                    path.append(prev[path[-1]])
                return list(reversed(path)) + [start]
            if w not in prev:
                prev[w] = v
                queue.append(w)
    return [start]


def import_cycles(project):
    """Each cycle of first-party imports (one entry per strongly connected group): a shortest
    cycle through it and every import line that keeps the group together."""
    edges = _module_edges(project)
    out = []
    for comp in _strongly_connected(edges):
        if len(comp) < 2:
            continue
        members = set(comp)
        cycle = _shortest_cycle(edges, comp[0], members)
        lines = {_where(project.modules[a], imp) for a in comp for b in sorted(edges[a])
                 if b in members for imp in edges[a][b]}
        out.append(" -> ".join(cycle) + "\n      "
                   + "\n      ".join(sorted(lines, key=_by_place)))
    return out


def _allowed(name, allowed):
    """Whether module `name` is one of `allowed`: a module's name, or ``"pkg.*"`` for the
    modules under the package ``pkg``."""
    return any(name == a or (a.endswith(".*") and name.startswith(a[:-1])) for a in allowed)


def body_imports(project, allowed=BODY_IMPORT_MODULES):
    """First-party imports not at module top, outside the modules allowed them."""
    out = []
    for mod in project.modules.values():
        if _allowed(mod.name, allowed):
            continue
        for imp in mod.imports:
            if not imp.top and project.first_party(imp.target):
                out.append(_where(mod, imp))
    return sorted(set(out), key=_by_place)   # one line per statement


def _ancestors(name):
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def heavy_at_startup(project, entry=CLI, heavy=HEAVY):
    """Top-level imports of `heavy` libraries in `entry` or any module it imports at module top
    (transitively; a package's ``__init__`` counts for each of its modules), with the chain."""
    edges = _module_edges(project, top_only=True, runtime_only=True)
    prev = {entry: None}
    queue = deque([entry])
    while queue:
        v = queue.popleft()
        for w in sorted(set(edges.get(v, ())) | set(_ancestors(v))):
            if w in project.modules and w not in prev:
                prev[w] = v
                queue.append(w)
    out = []
    for name in sorted(prev):
        mod = project.modules.get(name)
        if mod is None:
            continue
        chain = [name]
        while prev[chain[-1]] is not None:
            chain.append(prev[chain[-1]])
        for imp in mod.imports:
            if imp.top and not imp.type_checking and imp.target.split(".")[0] in heavy:
                out.append(f"{_where(mod, imp)}  [reached by "
                           f"{' <- '.join(chain) if len(chain) > 1 else 'itself'}]")
    return out


def layer_violations(project, lower=LOWER, upper=UPPER):
    """Imports (anywhere) of the `upper` package from modules of the `lower` one."""
    out = []
    for mod in project.modules.values():
        if mod.name.split(".")[0] != lower:
            continue
        for imp in mod.imports:
            if imp.target.split(".")[0] == upper:
                out.append(_where(mod, imp))
    return sorted(set(out), key=_by_place)


def relative_imports(project):
    """Every ``from . import x`` / ``from ..m import y``."""
    return sorted({_where(mod, imp) for mod in project.modules.values() for imp in mod.imports
                   if imp.relative}, key=_by_place)


def _numba_names(mod):
    """Local names bound to numba (``numba``, ``nb``) and to its decorators (``njit``)."""
    modules, decorators = set(), {}
    for node in ast.walk(mod.tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name == "numba":
                    modules.add(a.asname or "numba")
        elif isinstance(node, ast.ImportFrom) and node.module == "numba" and node.level == 0:
            for a in node.names:
                if a.name in NUMBA_DECORATORS:
                    decorators[a.asname or a.name] = a.name
    return modules, decorators


def _is_numba_decorator(dec, numba_modules, numba_decorators):
    if isinstance(dec, ast.Call):
        dec = dec.func
    if isinstance(dec, ast.Name):
        return dec.id in numba_decorators
    return (isinstance(dec, ast.Attribute) and dec.attr in NUMBA_DECORATORS
            and isinstance(dec.value, ast.Name) and dec.value.id in numba_modules)


def kernel_share(mod):
    """(lines in numba-compiled module-level functions, lines of the module)."""
    numba_modules, numba_decorators = _numba_names(mod)
    n_lines = len(mod.source.splitlines())
    compiled = set()
    for node in mod.tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and any(
                _is_numba_decorator(d, numba_modules, numba_decorators)
                for d in node.decorator_list):
            first = min([node.lineno] + [d.lineno for d in node.decorator_list])
            compiled.update(range(first, node.end_lineno + 1))
    return len(compiled), n_lines


def long_modules(project, max_lines=MAX_LINES):
    """Modules over `max_lines` lines that are not compiled-kernel modules."""
    out = []
    for mod in project.modules.values():
        compiled, n = kernel_share(mod)
        if n > max_lines and not 2 * compiled > n:
            out.append(f"{mod.rel}:1: {mod.name}: {n} lines ({compiled} in numba kernels, "
                       f"{100 * compiled / n:.0f}%)")
    return out


def n_parameters(node):
    """Parameters of a function definition: positional, keyword-only, ``*args``,
    ``**kwargs``; a first ``self``/``cls`` not counted."""
    a = node.args
    names = [p.arg for p in a.posonlyargs + a.args]
    n = len(names) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
    return n - 1 if names and names[0] in ("self", "cls") else n


def _public_functions(body, prefix=""):
    """``(qualified name, node)`` of the public functions and methods in `body` (module or
    class level; a private class's methods and nested functions are not public)."""
    for node in body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            if not _is_private(node.name):
                yield prefix + node.name, node
        elif isinstance(node, ast.ClassDef) and not _is_private(node.name):
            yield from _public_functions(node.body, f"{prefix}{node.name}.")
        elif isinstance(node, (ast.If, ast.Try)):
            yield from _public_functions(node.body, prefix)
            for part in getattr(node, "orelse", []), getattr(node, "finalbody", []):
                yield from _public_functions(part, prefix)
            for h in getattr(node, "handlers", []):
                yield from _public_functions(h.body, prefix)


def many_parameters(project, max_parameters=MAX_PARAMETERS):
    """Public functions and methods with more than `max_parameters` parameters."""
    out = []
    for mod in project.modules.values():
        for name, node in _public_functions(mod.tree.body):
            n = n_parameters(node)
            if n > max_parameters:
                out.append(f"{mod.rel}:{node.lineno}: {mod.name}.{name}: {n} parameters")
    return out


_PROBE = """\
import sys
heavy = {heavy!r}
loaded = {{}}
import {entry}
loaded["import"] = sorted(h for h in heavy if h in sys.modules)
{run}
loaded["run"] = sorted(h for h in heavy if h in sys.modules)
import json
print("\\n" + json.dumps(loaded))
"""


def heavy_loaded(entry, heavy, *, cwd, run=""):
    """{'import': [...], 'run': [...]}: the `heavy` modules in ``sys.modules`` of a fresh
    interpreter after ``import entry`` and after the statement `run`."""
    code = _PROBE.format(heavy=tuple(heavy), entry=entry, run=run)
    proc = subprocess.run([sys.executable, "-c", code], check=False, cwd=cwd,
                          capture_output=True, text=True)
    assert proc.returncode == 0, f"the import probe failed:\n{proc.stderr}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ----------------------------------------------------------------------------------------------
# the rules, on the real packages
# ----------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def project():
    return scan(ROOT, PACKAGES)


def test_scan_sees_the_packages(project):
    assert {CLI, "planner.design", "ident.sim.closedloop"} <= set(project.modules)
    # the command line is a package whose every module is on its start-up path
    commands = {m for m in project.modules if m.startswith(CLI + ".")} - {CLI + ".__main__"}
    assert {CLI + ".common", CLI + ".rank", CLI + ".dyno", CLI + ".drive"} <= commands
    edges = _module_edges(project, top_only=True, runtime_only=True)
    assert commands <= set(edges[CLI]) | set(edges[CLI + ".common"]), (
        commands - set(edges[CLI]))
    assert len(project.modules) > 40
    assert sum(len(m.imports) for m in project.modules.values()) > 300


def test_no_private_imports_across_modules(project):
    offenders = private_imports(project)
    assert not offenders, _message(
        "private names imported across modules", offenders,
        "make the name public (no underscore, documented, in __all__) in its module")


def test_no_import_cycles(project):
    offenders = import_cycles(project)
    assert not offenders, _message(
        "import cycles between first-party modules", offenders,
        "move the shared code to a module both can import")


def test_first_party_imports_at_module_top(project):
    offenders = body_imports(project)
    assert not offenders, _message(
        "first-party imports inside functions or classes", offenders,
        f"move them to the module top (only {sorted(BODY_IMPORT_MODULES)} may import in a "
        f"function)")


def test_cli_start_up_skips_heavy_libraries_statically(project):
    offenders = heavy_at_startup(project)
    assert not offenders, _message(
        f"top-level imports of heavy optional libraries on {CLI}'s start-up path", offenders,
        "import them inside the function that uses them, with a comment why")


def test_cli_start_up_skips_heavy_libraries():
    """A fresh interpreter: ``import planner.cli`` and ``shockplan --help`` load no heavy
    library (what is loaded is checked, not how long it takes)."""
    run = ("for argv in (['--help'], ['rank', '--help'], ['dyno', 'check', '--help'],\n"
           "             ['drive', 'from-track', '--help']):\n"
           "    try:\n        planner.cli.main(argv)\n"
           "    except SystemExit as e:\n        assert e.code in (0, None), e.code\n")
    loaded = heavy_loaded(CLI, HEAVY, cwd=ROOT, run=run)
    assert loaded == {"import": [], "run": []}, (
        f"heavy optional libraries loaded by `import {CLI}` / `shockplan --help`: {loaded}; "
        f"import them inside the function that uses them")


def test_ident_never_imports_planner(project):
    offenders = layer_violations(project)
    assert not offenders, _message(
        f"imports of {UPPER} from {LOWER}", offenders,
        f"{LOWER} is the lower layer: move what it needs into {LOWER}")


def test_no_relative_imports(project):
    offenders = relative_imports(project)
    assert not offenders, _message(
        "relative imports", offenders, "write them absolute (ident.… / planner.…)")


def test_no_module_over_max_lines(project):
    offenders = long_modules(project)
    assert not offenders, _message(
        f"modules over {MAX_LINES} lines that are not compiled-kernel modules", offenders,
        "split them by concept")


def test_no_public_function_over_max_parameters(project):
    offenders = many_parameters(project)
    assert not offenders, _message(
        f"public functions or methods with more than {MAX_PARAMETERS} parameters", offenders,
        "group the options of one concept in a keyword-only options object "
        "(planner.options), or make a kernel's helper private")


# ----------------------------------------------------------------------------------------------
# self-tests: each checker, on a synthetic package with one violation
# ----------------------------------------------------------------------------------------------

def _tree(tmp_path, files):
    """Write {relative path: source} under tmp_path (with the packages' __init__.py files)."""
    for rel, text in files.items():
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        for parent in path.relative_to(tmp_path).parents:
            if parent != Path(".") and not (tmp_path / parent / "__init__.py").exists():
                (tmp_path / parent / "__init__.py").write_text("", encoding="utf-8")
    return tmp_path


def test_self_private_imports(tmp_path):
    root = _tree(tmp_path, {
        "pkg/a.py": "_X = 1\nY = 2\n__version__ = '1'\ndef _f():\n    return _X\n",
        "pkg/sub/__init__.py": "from pkg.a import Y\n",
        "pkg/sub/_kern.py": "Z = 1\n",
        "pkg/sub/m.py": "from pkg.sub._kern import Z\n",                 # same package: fine
        "pkg/ok.py": ("import pkg.a as a\nfrom pkg import a as b\n"
                      "from pkg.a import Y, __version__\n"
                      "import os\nv = a.Y + b.Y + os._exit.__name__.__len__()\n"),
        "pkg/bad1.py": "from pkg.a import _X\n",
        "pkg/bad2.py": "import pkg.a as mod\ndef g():\n    return mod._f()\n",
        "pkg/bad3.py": "import pkg.a\nv = pkg.a._X\n",
        "pkg/bad4.py": "from pkg import sub\nv = sub._kern.Z\n",
        "pkg/bad5.py": "def h():\n    from pkg.sub import _kern\n",
        "pkg/a2.py": "_P = 1\nQ = _P\nimport pkg.a2\nR = pkg.a2._P\n",          # own privates
    })
    found = private_imports(scan(root, ("pkg",)))
    files = sorted({f.split(":")[0] for f in found})
    assert files == ["pkg/bad1.py", "pkg/bad2.py", "pkg/bad3.py", "pkg/bad4.py",
                     "pkg/bad5.py"], found
    assert any("pkg/bad2.py:3:" in f and "pkg.a._f" in f for f in found), found


def test_self_reexport_of_private_is_caught(tmp_path):
    root = _tree(tmp_path, {"pkg/a.py": "_X = 1\n",
                            "pkg/__init__.py": "from pkg.a import _X\n"})
    assert [f.split(":")[0] for f in private_imports(scan(root, ("pkg",)))] == [
        "pkg/__init__.py"]


def test_self_import_cycles(tmp_path):
    root = _tree(tmp_path, {
        "pkg/a.py": "import pkg.b\n",
        "pkg/b.py": "def f():\n    from pkg.c import x\n",   # a body import closes it too
        "pkg/c.py": "from pkg import a\nx = 1\n",
        "pkg/d.py": "import pkg.a\n",                          # feeds the cycle, not in it
        "pkg/sub/__init__.py": "from pkg.sub.e import y\n",    # a package re-export: no cycle
        "pkg/sub/e.py": "from pkg.a import b\ny = 1\n",
    })
    found = import_cycles(scan(root, ("pkg",)))
    assert len(found) == 1, found
    assert found[0].startswith("pkg.a -> pkg.b -> pkg.c -> pkg.a"), found
    assert "pkg/b.py:2:" in found[0] and "pkg/d.py" not in found[0]


def test_self_body_imports(tmp_path):
    root = _tree(tmp_path, {
        "pkg/a.py": "X = 1\n",
        "pkg/top.py": ("import typing\nif typing.TYPE_CHECKING:\n    from pkg.a import X\n"
                       "try:\n    from pkg import a\nexcept ImportError:\n    a = None\n"
                       "def f():\n    import json\n    return json\n"),
        "pkg/bad.py": "class C:\n    def m(self):\n        from pkg.a import X\n        return X\n",
        "pkg/cli.py": "def main():\n    from pkg.a import X\n",
        "pkg/cmd/run.py": "def main():\n    from pkg.a import X\n",      # under pkg.cmd.*
        "pkg/cmdx.py": "def main():\n    from pkg.a import X\n",        # not under it
    })
    found = body_imports(scan(root, ("pkg",)), allowed={"pkg.cli", "pkg.cmd.*"})
    assert len(found) == 2, found
    assert found[0].startswith("pkg/bad.py:3:") and "C.m" in found[0], found
    assert found[1].startswith("pkg/cmdx.py:2:"), found


def test_self_heavy_at_startup(tmp_path):
    root = _tree(tmp_path, {
        "pkg/cli.py": "from pkg.light import f\ndef main():\n    from pkg.slow import g\n",
        "pkg/light.py": "from pkg.sub.x import h\ndef f():\n    import matplotlib\n",
        "pkg/sub/__init__.py": "import casadi as ca\n",   # a package __init__ on the path
        "pkg/sub/x.py": "h = 1\n",
        "pkg/slow.py": "import cvxpy\n",                  # reached only in a function: fine
    })
    found = heavy_at_startup(scan(root, ("pkg",)), entry="pkg.cli")
    assert len(found) == 1 and found[0].startswith("pkg/sub/__init__.py:1:"), found
    assert "pkg.sub <- pkg.sub.x <- pkg.light <- pkg.cli" in found[0], found


def test_self_heavy_at_startup_of_a_package(tmp_path):
    """The command line as a package: its __init__ imports the command modules, whose
    module tops are on the start-up path (their functions' imports are not)."""
    root = _tree(tmp_path, {
        "pkg/cli/__init__.py": "from pkg.cli import a, b\n",
        "pkg/cli/a.py": "def run():\n    import dask\n",              # in a function: fine
        "pkg/cli/b.py": "from pkg.cli.common import x\n",
        "pkg/cli/common.py": "import openpyxl\nx = 1\n",
    })
    found = heavy_at_startup(scan(root, ("pkg",)), entry="pkg.cli")
    assert len(found) == 1 and found[0].startswith("pkg/cli/common.py:1:"), found
    assert "pkg.cli.common <- pkg.cli.b <- pkg.cli" in found[0], found


def test_self_heavy_loaded(tmp_path):
    root = _tree(tmp_path, {
        "fakecli.py": "import fakeheavy_a\ndef main():\n    import fakeheavy_b\n",
        "fakeheavy_a.py": "", "fakeheavy_b.py": "", "fakeheavy_c.py": ""})
    heavy = ("fakeheavy_a", "fakeheavy_b", "fakeheavy_c")
    loaded = heavy_loaded("fakecli", heavy, cwd=root, run="fakecli.main()")
    assert loaded == {"import": ["fakeheavy_a"], "run": ["fakeheavy_a", "fakeheavy_b"]}


def test_self_layer_violations(tmp_path):
    root = _tree(tmp_path, {
        "low/a.py": "import os\ndef f():\n    import high.b\n",
        "low/ok.py": "import low.a\n",
        "high/b.py": "import low.a\n",
    })
    found = layer_violations(scan(root, ("low", "high")), lower="low", upper="high")
    assert len(found) == 1 and found[0].startswith("low/a.py:3:"), found


def test_self_relative_imports(tmp_path):
    root = _tree(tmp_path, {
        "pkg/a.py": "X = 1\n",
        "pkg/sub/b.py": "from ..a import X\nfrom pkg.a import X as Y\n",
        "pkg/__init__.py": "from . import a\n",
    })
    project = scan(root, ("pkg",))
    found = relative_imports(project)
    assert sorted(f.split(":")[0] for f in found) == ["pkg/__init__.py", "pkg/sub/b.py"], found
    # resolved for the other rules too: ..a from pkg.sub.b is pkg.a
    assert [i.target for i in project.modules["pkg.sub.b"].imports] == ["pkg.a", "pkg.a"]
    assert [i.target for i in project.modules["pkg"].imports] == ["pkg.a"]


def test_self_long_modules(tmp_path):
    kernel = "@nb.njit(cache=True)\ndef k(x):\n" + "    x = x + 1\n" * 40 + "    return x\n"
    plain = "def p(x):\n" + "    x = x + 1\n" * 40 + "    return x\n"
    root = _tree(tmp_path, {
        "pkg/long.py": plain * 3,                                   # 126 lines, no kernels
        "pkg/kern.py": "import numba as nb\n" + kernel * 2 + plain,  # 2/3 compiled
        "pkg/half.py": "from numba import njit as J\n" + kernel.replace("nb.njit", "J") + plain * 2,
        "pkg/short.py": plain,
    })
    project = scan(root, ("pkg",))
    assert kernel_share(project.modules["pkg.half"])[0] == 43
    found = long_modules(project, max_lines=100)
    assert sorted(f.split(":")[0] for f in found) == ["pkg/half.py", "pkg/long.py"], found


def test_self_many_parameters(tmp_path):
    def sig(n, first=""):
        return ", ".join(([first] if first else []) + [f"a{k}" for k in range(n)])
    root = _tree(tmp_path, {
        "pkg/a.py": (f"def wide({sig(17)}):\n    pass\n"                    # 17: caught
                     f"def ok({sig(16)}):\n    pass\n"                      # 16: fine
                     f"def _private({sig(30)}):\n    pass\n"               # private: exempt
                     f"def star({sig(15)}, *args, **kwargs):\n    pass\n"  # 17 with both
                     f"def kwonly({sig(10)}, *, {', '.join(f'k{k}' for k in range(7))}):\n"
                     "    pass\n"                                          # 17
                     f"def outer():\n    def inner({sig(20)}):\n        pass\n"),
        "pkg/b.py": (f"class C:\n    def m({sig(16, 'self')}):\n        pass\n"  # 16 + self
                     f"    @classmethod\n    def c({sig(17, 'cls')}):\n        pass\n"
                     f"class _P:\n    def m({sig(20, 'self')}):\n        pass\n"
                     "import numba as nb\n"
                     f"@nb.njit\ndef kern({sig(18)}):\n    pass\n"),         # kernels too
    })
    project = scan(root, ("pkg",))
    found = many_parameters(project)
    assert sorted(f.split(": ")[1] for f in found) == [
        "pkg.a.kwonly", "pkg.a.star", "pkg.a.wide", "pkg.b.C.c", "pkg.b.kern"], found
    assert n_parameters(ast.parse(f"def f({sig(3, 'self')}): pass").body[0]) == 3
