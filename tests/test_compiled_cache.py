"""numba's cache kept in step with the sources (systems/compiled_cache.py): numba keys a cached kernel by its own file
only, so a kernel whose callee's module changed would keep running the callee's old code."""

from __future__ import annotations

import importlib.util
import sys

from simrun.systems import compiled_cache
from simrun.systems.compiled_cache import keep_fresh, sources_digest

KERNEL = '''
import numba

@numba.njit(cache=True)
def doubled(x):
    return 2.0 * x
'''


def test_the_digest_follows_the_compiled_modules_only(tmp_path):
    (tmp_path / "systems").mkdir()
    kernel, plain = tmp_path / "systems" / "kernel.py", tmp_path / "systems" / "plain.py"
    kernel.write_text(KERNEL)
    plain.write_text("x = 1\n")
    first = sources_digest.__wrapped__(tmp_path)
    plain.write_text("x = 2\n")
    assert sources_digest.__wrapped__(tmp_path) == first  # no compiled kernel there
    kernel.write_text(KERNEL.replace("2.0", "3.0"))
    assert sources_digest.__wrapped__(tmp_path) != first


def _compiled_module(tmp_path):
    path = tmp_path / "kernel_module.py"
    path.write_text(KERNEL)
    spec = importlib.util.spec_from_file_location("kernel_module", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["kernel_module"] = module
    spec.loader.exec_module(module)
    assert module.doubled(2.0) == 4.0  # compiled, and cached next to it
    return module


def test_cache_files_compiled_from_other_sources_are_removed(tmp_path, monkeypatch):
    try:
        module = _compiled_module(tmp_path)
        cache = tmp_path / "__pycache__"
        compiled = sorted(path.name for path in cache.glob("kernel_module.*.nb[ic]"))
        assert compiled, "numba must have cached the kernel"
        monkeypatch.setattr(compiled_cache, "sources_digest", lambda: "today")
        keep_fresh(vars(module))  # no record yet: compiled before the check, so from unknown sources
        assert not list(cache.glob("kernel_module.*.nb[ic]"))
        assert (cache / "kernel_module.simrun-sources").read_text() == "today"
        module = _compiled_module(tmp_path)  # imported again: compiled again, and cached
        assert list(cache.glob("kernel_module.*.nb[ic]"))
        keep_fresh(vars(module))  # the same sources: kept
        assert list(cache.glob("kernel_module.*.nb[ic]"))
        monkeypatch.setattr(compiled_cache, "sources_digest", lambda: "tomorrow")  # a callee's module changed
        keep_fresh(vars(module))
        assert not list(cache.glob("kernel_module.*.nb[ic]"))
        assert (cache / "kernel_module.simrun-sources").read_text() == "tomorrow"
    finally:
        sys.modules.pop("kernel_module", None)


def test_every_module_with_cached_kernels_keeps_its_cache_fresh():
    """A new compiled module that forgot the call would be stale again: each one calls keep_fresh."""
    root = compiled_cache.Path(compiled_cache.__file__).resolve().parent.parent
    missing = [str(path.relative_to(root)) for folder in compiled_cache.COMPILED_FOLDERS
               for path in (root / folder).rglob("*.py")
               if compiled_cache.CACHE_MARK in path.read_text() and "keep_fresh(globals())" not in path.read_text()]
    assert not missing
