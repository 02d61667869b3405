"""Rendered scenes kept between runs (pipeline.scene_cache): the same bytes, or a render."""

from __future__ import annotations

import json

import pytest

from pipeline import scene_cache, scenes

TINY = {"cameras.width": 64, "cameras.height": 48, "cameras.focal_px": 83.2,
        "shape.triangles": 2000, "render.supersample": 1}


def _tree(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def cache(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    monkeypatch.setenv(scene_cache.ENV, str(root))
    return root


def test_second_render_is_the_cached_copy_byte_for_byte(tmp_path, cache, monkeypatch):
    recipe = scenes.load_recipe(overrides=TINY)
    first = scenes.render_scene(recipe, tmp_path / "a", progress=False)
    entries = [p for p in cache.iterdir() if not p.name.startswith(".")]
    assert len(entries) == 1 and (entries[0] / "index.json").is_file()

    def no_render(*args, **kwargs):
        raise AssertionError("rendered again although the scene is cached")

    monkeypatch.setattr(scenes, "build_scene", no_render)
    second = scenes.render_scene(recipe, tmp_path / "b", progress=False)
    assert _tree(first) == _tree(second)


def test_another_recipe_or_a_damaged_entry_renders(tmp_path, cache):
    recipe = scenes.load_recipe(overrides=TINY)
    scenes.render_scene(recipe, tmp_path / "a", progress=False)
    other = scenes.load_recipe(overrides={**TINY, "seed": 2})
    assert scene_cache.cache_key(recipe, "x") != scene_cache.cache_key(other, "x")
    (entry,) = [p for p in cache.iterdir() if not p.name.startswith(".")]
    index = json.loads((entry / "index.json").read_text())
    damaged = entry / next(iter(index["files"]))
    damaged.write_bytes(damaged.read_bytes()[:-1])  # a truncated file
    again = scenes.render_scene(recipe, tmp_path / "b", progress=False)
    assert _tree(again) == _tree(tmp_path / "a")  # rendered, not the damaged copy


def test_cache_off(tmp_path, monkeypatch):
    monkeypatch.setenv(scene_cache.ENV, "off")
    assert scene_cache.cache_root() is None
    scenes.render_scene(scenes.load_recipe(overrides=TINY), tmp_path / "a", progress=False)
    assert scene_cache.fetch("0" * 64, tmp_path) is False


def test_pruned_to_the_most_recent_entries(tmp_path, cache, monkeypatch):
    monkeypatch.setattr(scene_cache, "MAX_ENTRIES", 2)
    folder = tmp_path / "src"
    folder.mkdir()
    (folder / "f.txt").write_text("x")
    for k in range(4):
        scene_cache.store(f"{k:064d}", folder)
    kept = sorted(p.name for p in cache.iterdir())
    assert len(kept) == 2 and f"{3:064d}" in kept
