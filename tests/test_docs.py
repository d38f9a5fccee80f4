"""Every public name of the packages is documented, and every module's doctests run.

One test for the whole project (as python-control does), instead of a copy per module.
"""

import doctest
import importlib
import inspect
import pkgutil

import pytest

import ident
import planner

MODULES = sorted(
    info.name
    for pkg in (ident, planner)
    for info in pkgutil.walk_packages(pkg.__path__, prefix=f"{pkg.__name__}.")
    if not info.name.rsplit(".", 1)[-1].startswith("_")
)


@pytest.mark.parametrize("modname", MODULES)
def test_every_public_name_is_documented(modname):
    mod = importlib.import_module(modname)
    assert inspect.getdoc(mod), f"{modname} has no module docstring"
    for name in getattr(mod, "__all__", ()):
        obj = getattr(mod, name)
        if inspect.isclass(obj) or inspect.isfunction(obj):
            assert inspect.getdoc(obj), f"{modname}.{name}"
            if inspect.isclass(obj):
                for meth_name, meth in vars(obj).items():
                    if meth_name.startswith("_") or not (inspect.isfunction(meth)
                                                         or isinstance(meth, property)):
                        continue
                    assert inspect.getdoc(meth), f"{modname}.{name}.{meth_name}"


@pytest.mark.parametrize("modname", MODULES)
def test_docstring_examples_run(modname):
    mod = importlib.import_module(modname)
    result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    if result.attempted == 0:
        # a module with no example has nothing to pass: reported as skipped, never as a pass
        pytest.skip(f"{modname} has no docstring example")
    assert result.failed == 0, f"{result.failed} doctest(s) failed in {modname}"
