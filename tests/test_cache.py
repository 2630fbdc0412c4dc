"""The stage cache: reused stages give byte-identical runs; a changed input reruns what depends on it."""

import json
import os
import pickle

import numpy as np
import pytest

from fracture.pipeline import runner
from fracture.pipeline.cache import StageCache
from fracture.pipeline.config import load_config
from fracture.io.obj import write_obj
from fracture.mesh.primitives import sheet


def run(cfg, out, cache):
    done = runner.run(cfg, out, progress=False, cache=cache)
    return json.loads((done / "manifest.json").read_text())


def untimed(stats):
    """A run's statistics without the refinement's and the search's seconds (a clock's, not the run's,
    figures)."""
    refine = {k: v for k, v in stats["refine"].items() if k != "phase_seconds"}
    if refine.get("search") is not None:
        refine["search"] = {k: v for k, v in refine["search"].items() if k != "seconds"}
    return {**stats, "refine": refine}


def reuse(manifest):
    return {name: info.get("cache") for name, info in manifest["stages"].items()}


def test_an_identical_run_reuses_every_stage_and_is_byte_identical(tmp_path, small_config):
    cache = StageCache(tmp_path / "cache")
    cfg = load_config(small_config)
    first = run(cfg, tmp_path / "a", cache)
    assert set(reuse(first).values()) == {"stored"}
    second = run(cfg, tmp_path / "b", cache)
    assert set(reuse(second).values()) == {"reused"}
    assert second["stages"]["refine"]["made_by"] == str(tmp_path / "a")
    plain = run(cfg, tmp_path / "c", None)
    assert reuse(plain) == {name: None for name in plain["stages"]}
    for m in (second, plain):
        assert m["files"] == first["files"]  # every file: same bytes (sha256)
        assert m["counts"] == first["counts"] and m["notes"] == first["notes"]
    assert second["stats"] == first["stats"] and untimed(plain["stats"]) == untimed(first["stats"])


def test_a_psi_change_reuses_the_coarse_stage_and_the_strength(tmp_path, small_config):
    cache = StageCache(tmp_path / "cache")
    first = run(load_config(small_config), tmp_path / "a", cache)
    changed = run(load_config(small_config, ["psi.stress_weight=1.5"]), tmp_path / "b", cache)
    assert reuse(changed) == {"coarse": "reused", "fields": "stored", "refine": "stored", "animate": "stored"}
    assert changed["files"]["fields/zeta.npy"] == first["files"]["fields/zeta.npy"]
    assert changed["files"]["fields/psi.npy"] != first["files"]["fields/psi.npy"]
    # the same change without the cache: the same run
    plain = run(load_config(small_config, ["psi.stress_weight=1.5"]), tmp_path / "c", None)
    assert plain["files"] == changed["files"]
    # only the refinement's settings changed: the fields are reused too
    refine_only = run(load_config(small_config, ["refine.iterations=3"]), tmp_path / "d", cache)
    assert reuse(refine_only) == {"coarse": "reused", "fields": "reused", "refine": "stored", "animate": "stored"}


def test_a_psi_change_reuses_the_search_band_and_the_volumes_and_gives_the_run_without_the_cache(
        tmp_path, small_config, monkeypatch):
    import fracture.refine.engine as engine
    import fracture.refine.search as search
    import fracture.refine.volumes as volumes

    cache = StageCache(tmp_path / "cache")
    searched = ["refine.search=graphcut", "refine.iterations=3"]
    first = run(load_config(small_config, searched), tmp_path / "a", cache)
    assert first["stats"]["refine"]["search"]["free_nodes"] > 0
    assert len(list((tmp_path / "cache" / "search band").iterdir())) == 1
    assert len(list((tmp_path / "cache" / "coarse volumes").iterdir())) == 1

    def not_again(*args, **kwargs):
        raise AssertionError("the band or the coarse volumes were made again")

    with monkeypatch.context() as m:  # neither reads psi: a psi change finds them in the cache
        m.setattr(engine, "search_band", not_again)
        m.setattr(search, "search_band", not_again)
        m.setattr(volumes, "measure_volumes", not_again)
        changed = run(load_config(small_config, [*searched, "psi.stress_weight=1.5"]), tmp_path / "b", cache)
    assert changed["stats"]["refine"]["search"]["free_nodes"] == first["stats"]["refine"]["search"]["free_nodes"]
    plain = run(load_config(small_config, [*searched, "psi.stress_weight=1.5"]), tmp_path / "c", None)
    assert plain["files"] == changed["files"] and untimed(plain["stats"]) == untimed(changed["stats"])
    assert changed["stats"]["refine"]["piece_volume_shares"] == plain["stats"]["refine"]["piece_volume_shares"]
    # another band, core or grid is another band; only another grid other volumes
    for k, other in enumerate(["refine.band=6", "refine.core=0.3", "grid.resolution=18"]):
        run(load_config(small_config, [*searched, other]), tmp_path / f"d{k}", cache)
        assert len(list((tmp_path / "cache" / "search band").iterdir())) == 2 + k
        assert len(list((tmp_path / "cache" / "coarse volumes").iterdir())) == 1 + (other.startswith("grid"))


def test_a_changed_input_file_invalidates_the_stages_after_it(tmp_path, small_config):
    cache = StageCache(tmp_path / "cache")
    run(load_config(small_config), tmp_path / "a", cache)
    SV, SF = sheet(lambda u, v: np.stack([1.1 + 0.1 * u, u, v], 1), (0, 1), (0, 0.5), 5, 3)
    write_obj(small_config.parent / "cut.obj", SV, SF)  # the same path, other content
    again = run(load_config(small_config), tmp_path / "b", cache)
    assert set(reuse(again).values()) == {"stored"}


def test_the_key_holds_every_source_file_and_a_code_change_invalidates_every_stage(tmp_path, small_config,
                                                                                 monkeypatch):
    from fracture.pipeline import cache as cache_module

    root, files = cache_module.source_files()
    names = {str(p.relative_to(root)) for p in files}
    assert {"fracture/pipeline/cache.py", "fracture/refine/engine.py", "fields/pyramid.py"} <= names
    cache = StageCache(tmp_path / "cache")
    run(load_config(small_config), tmp_path / "a", cache)
    edited = tmp_path / "src"  # the same sources with one more line in one file
    for p in files:
        copy = edited / p.relative_to(root)
        copy.parent.mkdir(parents=True, exist_ok=True)
        copy.write_bytes(p.read_bytes() + (b"# changed\n" if p.name == "tiling.py" else b""))
    monkeypatch.setattr(cache_module, "source_files",
                        lambda: (edited, [edited / p.relative_to(root) for p in files]))
    cache_module.code_version.cache_clear()
    try:
        again = run(load_config(small_config), tmp_path / "b", cache)
    finally:
        cache_module.code_version.cache_clear()
    assert set(reuse(again).values()) == {"stored"}


def test_an_interrupted_store_leaves_no_entry_and_stale_ones_go(tmp_path, small_config, monkeypatch):
    cache = StageCache(tmp_path / "cache")
    real = pickle.dump

    def killed(obj, f, *args, **kwargs):
        real(obj, f, *args, **kwargs)
        raise KeyboardInterrupt  # as if the run were stopped while it stored the stage

    monkeypatch.setattr(pickle, "dump", killed)
    with pytest.raises(KeyboardInterrupt):
        run(load_config(small_config), tmp_path / "a", cache)
    monkeypatch.setattr(pickle, "dump", real)
    assert not (tmp_path / "a").exists()
    assert [p for p in (tmp_path / "cache").rglob("*") if p.is_dir() and p.parent.parent == tmp_path / "cache"] == []
    assert list((tmp_path / "cache").glob("*/.*")) == []  # nothing half-written
    # what a run killed outright leaves (its process gone) is removed by the next run
    stale = tmp_path / "cache" / "coarse" / f".0123456789ab.partial-{2 ** 22 + 7}-x"
    stale.mkdir(parents=True)
    (stale / "meta.json").write_text("{")
    manifest = run(load_config(small_config), tmp_path / "b", cache)
    assert set(reuse(manifest).values()) == {"stored"} and not stale.exists()


def test_the_cache_keeps_to_its_size_by_dropping_what_was_read_longest_ago(tmp_path, small_config):
    cache = StageCache(tmp_path / "cache")
    run(load_config(small_config), tmp_path / "a", cache)
    entries = cache.entries()
    assert len(entries) >= 4 and cache.size() > 0
    oldest = min(entries, key=lambda p: (p / "meta.json").stat().st_mtime)
    os.utime(oldest / "meta.json", (1, 1))
    cache.max_bytes = cache.size() - 1
    assert cache.trim() == [oldest] and not oldest.exists()
    assert all((p / "meta.json").is_file() for p in cache.entries())


def test_the_command_line_uses_the_cache_unless_told_not_to(tmp_path, small_config):
    from fracref.cli import main

    env = {"FRACREF_CACHE_DIR": str(tmp_path / "cache")}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        assert main(["run", str(small_config), "--out", str(tmp_path / "a"), "--quiet"]) == 0
        assert main(["run", str(small_config), "--out", str(tmp_path / "b"), "--quiet"]) == 0
        assert main(["run", str(small_config), "--out", str(tmp_path / "c"), "--quiet", "--no-cache"]) == 0
    finally:
        for k, v in old.items():
            os.environ[k] = v if v is not None else ""
    stages = lambda d: json.loads((tmp_path / d / "manifest.json").read_text())["stages"]  # noqa: E731
    assert {s["cache"] for s in stages("b").values()} == {"reused"}
    assert all("cache" not in s for s in stages("c").values())


def test_entries_are_written_beside_later_stages_and_are_whole_when_a_later_stage_fails(tmp_path, small_config):
    """The runner stores a stage's entry in a thread while the next stages run; a later stage's failure
    waits for it: the earlier stages' entries are complete, nothing is half-written, the run leaves no
    directory, and the next run reuses them."""
    from fracture.pipeline.stages import STAGES, Stage

    cache = StageCache(tmp_path / "cache")

    def fails(ctx):
        raise RuntimeError("the refinement failed")

    broken = tuple(Stage(s.name, fails) if s.name == "refine" else s for s in STAGES)
    with pytest.raises(RuntimeError):
        runner.run(load_config(small_config), tmp_path / "a", progress=False, cache=cache, stages=broken)
    assert not (tmp_path / "a").exists()
    assert list((tmp_path / "cache").glob("*/.*")) == []  # nothing half-written
    for stage in ("coarse", "fields"):
        entries = list((tmp_path / "cache" / stage).iterdir())
        assert len(entries) == 1 and (entries[0] / "meta.json").is_file() and (entries[0] / "products.pkl").is_file()
    manifest = run(load_config(small_config), tmp_path / "b", cache)
    assert reuse(manifest) == {"coarse": "reused", "fields": "reused", "refine": "stored", "animate": "stored"}
