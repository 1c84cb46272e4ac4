"""The render cache: a hit returns exactly what was rendered, and any change of scene, exposure or renderer
misses. Rendering is replaced by a counting fake (the cache's logic does not depend on the pixels)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cellctl.cli import main
from cellctl.sim import render_cache
from cellctl.sim.look import look_for
from cellctl.sim.render import RenderedPair
from cellctl.sim.render_cache import RenderCache, scene_key
from cellctl.sim.scene import SoleScene
from tests.sim_rig import half_size_rig


class CountingRenders:
    """Stands in for SoleScene.render / render_empty: distinct random images per call, counted."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, scene: SoleScene, shot: int = 0) -> RenderedPair:
        self.calls += 1
        rng = np.random.default_rng(self.calls)
        image = rng.integers(0, 256, (8, 10, 3), dtype=np.uint8)
        depth = rng.normal(500.0, 1.0, (8, 10)).astype(np.float32)
        depth[0, 0] = np.nan
        return RenderedPair(image, image[:, ::-1].copy(), depth, depth > 500.0)


@pytest.fixture
def renders(monkeypatch: pytest.MonkeyPatch) -> CountingRenders:
    fake = CountingRenders()
    monkeypatch.setattr(SoleScene, "render", lambda self: fake(self))
    monkeypatch.setattr(SoleScene, "render_empties", lambda self, shots: [fake(self, shot) for shot in shots])
    monkeypatch.setattr(render_cache, "render_exposures", lambda scene, shots: [fake(scene, shot) for shot in shots])
    return fake


def scene(seed: int = 5, color: str = "white", variations: tuple[str, ...] = ()) -> SoleScene:
    return SoleScene.random(seed, color, half_size_rig(), look_for(variations, seed))


def test_a_hit_returns_exactly_the_render_and_renders_nothing(tmp_path: Path, renders: CountingRenders) -> None:
    cache = RenderCache(tmp_path)
    first = cache.render(scene())
    again = RenderCache(tmp_path).render(scene())  # another process, same directory
    assert renders.calls == 1
    for name in ("left", "right", "depth_left", "sole_mask_left"):
        np.testing.assert_array_equal(getattr(again, name), getattr(first, name))
    cache.render_empty(scene(), 1)
    cache.render_empty(scene(), 1)
    assert renders.calls == 2 and cache.hits == 1 and cache.misses == 2
    with pytest.raises(ValueError, match="numbered from 1"):
        cache.render_empty(scene(), 0)
    assert len(cache.render_empties(scene(), [1, 2, 3])) == 3 and renders.calls == 4


def test_any_change_of_scene_exposure_or_renderer_misses(monkeypatch: pytest.MonkeyPatch) -> None:
    base = scene()
    keys = {
        scene_key(base, 0),
        scene_key(base, 1),
        scene_key(base, 2),
        scene_key(scene(6), 0),
        scene_key(scene(color="black"), 0),
        scene_key(scene(variations=("gain-low",)), 0),
        scene_key(replace(base, look=replace(base.look, right_gain=0.9)), 0),
    }
    assert len(keys) == 7 and scene_key(scene(), 0) in keys
    monkeypatch.setattr(render_cache, "renderer_version", lambda: "another simulator")
    assert scene_key(base, 0) not in keys


def test_the_renderer_version_follows_the_simulators_source() -> None:
    version = render_cache.renderer_version()
    sources = sorted(Path(render_cache.__file__).parent.glob("*.py"))
    assert len(version) == 16 and len(sources) > 5
    render_cache.renderer_version.cache_clear()
    assert render_cache.renderer_version() == version


def test_a_damaged_entry_is_rendered_again(tmp_path: Path, renders: CountingRenders) -> None:
    cache = RenderCache(tmp_path)
    cache.render(scene())
    (entry,) = tmp_path.glob("*.npz")
    entry.write_bytes(entry.read_bytes()[:100])  # a writer killed half way
    cache.render(scene())
    assert renders.calls == 2 and cache.render(scene()) is not None and renders.calls == 2


def test_prefilling_processes_share_the_work(tmp_path: Path, renders: CountingRenders) -> None:
    cache = RenderCache(tmp_path)
    lock = tmp_path / f"{scene_key(scene(), 0)}.lock"
    lock.touch()  # another process is rendering this scene
    assert cache.prefill(scene(), [0, 1, 2]) == 0 and renders.calls == 0
    lock.unlink()
    assert cache.prefill(scene(), [0, 1, 2]) == 3 and renders.calls == 3
    assert cache.prefill(scene(), [0, 1, 2]) == 0 and cache.prefill(scene(), [0, 1, 2, 3]) == 1
    assert not lock.exists() and renders.calls == 4


def test_the_scenes_exposures_are_cached_apart_from_the_empty_tables(tmp_path: Path, renders: CountingRenders) -> None:
    cache = RenderCache(tmp_path)
    first = cache.render(scene())
    exposures = cache.render_exposures(scene(), 3)  # the scene's own render is its first exposure: 2 new
    assert renders.calls == 3 and exposures[0].left.tobytes() == first.left.tobytes()
    assert len({e.left.tobytes() for e in exposures}) == 3
    cache.render_empties(scene(), [1, 2])
    assert renders.calls == 5 and len(RenderCache(tmp_path).render_exposures(scene(), 3)) == 3 and renders.calls == 5
    assert cache.prefill(scene(), [0, -1, -2, -3, 1, 2]) == 1 and renders.calls == 6


def test_the_first_exposure_is_the_scene_and_the_others_differ_by_noise_alone() -> None:
    grey = scene(7, "grey")
    first, second = render_cache.render_exposures(grey, [0, -1])
    np.testing.assert_array_equal(first.left, grey.render().left)
    noise = second.left.astype(np.int16) - first.left.astype(np.int16)
    assert 0.5 < float(np.std(noise)) < 3.0 and abs(float(np.mean(noise))) < 0.1
    with pytest.raises(ValueError, match="shots 0, -1, -2"):
        render_cache.render_exposures(grey, [1])


def test_several_exposures_rendered_together_equal_each_rendered_alone() -> None:
    together = scene(7, "grey", ("shadows",)).render_empties([1, 3])
    alone = scene(7, "grey", ("shadows",)).render_empty(3)
    np.testing.assert_array_equal(together[1].left, alone.left)
    np.testing.assert_array_equal(together[1].right, alone.right)
    assert np.abs(together[0].left.astype(int) - alone.left.astype(int)).max() > 0  # other noise


def test_cli_render_only_fills_the_cache_and_needs_a_directory(
    tmp_path: Path, renders: CountingRenders, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench-sole", "--render-only", "--soles", "1"]) == 2
    assert "--render-only needs --cache" in capsys.readouterr().err
    calib = tmp_path / "calib.yaml"
    half_size_rig().save(calib)
    args = ["bench-sole", "--matrix", "--soles", "2", "--calib", str(calib), "--cache", str(tmp_path / "c")]
    assert main([*args, "--render-only", "--taught"]) == 0  # per sole 4 exposures of it, 4 of the empty table
    assert renders.calls == 2 * 8 and len(list((tmp_path / "c").glob("*.npz"))) == 16
    assert main([*args, "--render-only", "--taught"]) == 0 and renders.calls == 16
    assert main([*args, "--render-only", "--frames", "5"]) == 0 and renders.calls == 18
    assert main([*args, "--render-only", "--frames", "0"]) == 2
    assert "--frames must be 1..16" in capsys.readouterr().err
