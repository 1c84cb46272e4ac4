"""An on-disk cache of rendered scenes, so benchmark runs re-measure without re-rendering.

Rendering a sole costs tens of seconds of CPU (five renders for a taught sole: the scene and four
exposures of the empty table); measuring it costs a few. `cellctl bench-sole --cache DIR` keeps every
render here. A render is stored under a key that covers everything that decides its pixels:

* the scene: seed, colour, look (every variation switch), the rig's calibration and the camera pose;
* the exposure: which shot (the scene itself, a further exposure of it or an empty-table exposure, each with
  its own sensor noise);
* the renderer: a hash of the source of every other module of `cellctl.sim`, so a change to the simulator
  (a new material, a fixed shadow ray) can never serve an image rendered by older code.

Entries are written atomically (temporary file, then rename), so a background run filling the cache and a
measuring run reading it can share one directory.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import asdict
from functools import lru_cache
from pathlib import Path

import numpy as np

from cellctl.sim.render import RenderedPair, SceneRenderer
from cellctl.sim.scene import SoleScene
from cellctl.vision.teach import calibration_fingerprint

SCENE_SHOT = 0  # the scene with its sole; its further exposures are shots -1, -2, ...; the empty table's 1, 2, ...
# Sensor-noise seed of the scene's exposure k (shot -k): its seed + k times this prime (the empty table's exposures
# step by 7919, SoleScene.render_empties), so no two exposures of a matrix share their noise.
EXPOSURE_SEED_STEP = 104729


def exposure_shots(count: int) -> list[int]:
    """The shots of `count` exposures of the scene with its sole, as the cell's cycle takes them: 0, -1, -2, ..."""
    return [-k for k in range(count)]


def render_exposures(scene: SoleScene, shots: list[int]) -> list[RenderedPair]:
    """Exposures of the scene with its sole (`exposure_shots`; 0 is `SoleScene.render` itself), ray-cast and shaded
    once: only the sensor noise differs. Here, not in cellctl.sim.scene, so that adding it left every stored render
    valid (`renderer_version` hashes that module)."""
    if max(shots) > SCENE_SHOT:
        raise ValueError(f"the scene's exposures are shots 0, -1, -2, ..., got {max(shots)}")
    renderer = SceneRenderer(scene.calib, scene.camera_pose, scene.sole, scene.color, scene.seed, scene.look)
    return renderer.render_shots(
        [None if shot == SCENE_SHOT else scene.seed - EXPOSURE_SEED_STEP * shot for shot in shots]
    )


@lru_cache(maxsize=1)
def renderer_version() -> str:
    """Hash of the simulator's source (every .py file of cellctl.sim but this one): the renderer's version."""
    digest = hashlib.sha256()
    for path in sorted(p for p in Path(__file__).parent.glob("*.py") if p.name != Path(__file__).name):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def scene_key(scene: SoleScene, shot: int) -> str:
    """Cache key of one render of `scene`: scene, exposure and renderer version (see the module doc)."""
    description = {
        "seed": scene.seed,
        "color": scene.color,
        "look": asdict(scene.look),
        "calib": calibration_fingerprint(scene.calib),
        "camera_pose": np.round(scene.camera_pose, 9).tolist(),
        "sole": None if scene.sole is None else repr(scene.sole),
        "shot": shot,
        "renderer": renderer_version(),
    }
    return hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()[:32]


class RenderCache:
    """Renders of scenes kept in a directory; a missing or unreadable entry is rendered and stored."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.hits = 0
        self.misses = 0

    def render(self, scene: SoleScene) -> RenderedPair:
        """The scene with its sole (`SoleScene.render`)."""
        return self._get(scene, SCENE_SHOT)

    def render_exposures(self, scene: SoleScene, count: int) -> list[RenderedPair]:
        """`count` exposures of the scene with its sole (`render_exposures`): the missing ones rendered in one go."""
        return self._shots(scene, exposure_shots(count), lambda missing: render_exposures(scene, missing))

    def render_empty(self, scene: SoleScene, shot: int) -> RenderedPair:
        """An exposure of the empty table (`SoleScene.render_empty`)."""
        return self.render_empties(scene, [shot])[0]

    def render_empties(self, scene: SoleScene, shots: list[int]) -> list[RenderedPair]:
        """Exposures of the empty table (`SoleScene.render_empties`): the missing ones rendered in one go."""
        if min(shots) < 1:
            raise ValueError(f"empty-table exposures are numbered from 1, got {min(shots)}")
        return self._shots(scene, shots, scene.render_empties)

    def prefill(self, scene: SoleScene, shots: list[int]) -> int:
        """Render the missing `shots` (0: the scene, -1...: its further exposures, 1...: empty-table exposures) of a
        scene into the cache,
        unless another process is rendering this scene (a lock file). Returns how many it rendered.

        Several processes prefilling the same list of scenes so share the work.
        """
        missing = [shot for shot in shots if not self._path(scene, shot).exists()]
        if not missing:
            return 0
        lock = self._path(scene, SCENE_SHOT).with_suffix(".lock")
        try:
            os.close(os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return 0
        try:
            if SCENE_SHOT in missing:
                self._get(scene, SCENE_SHOT)
            further = [shot for shot in missing if shot < SCENE_SHOT]
            if further:
                self.render_exposures(scene, 1 - min(further))
            empties = [shot for shot in missing if shot > SCENE_SHOT]
            if empties:
                self.render_empties(scene, empties)
        finally:
            lock.unlink(missing_ok=True)
        return len(missing)

    def _shots(
        self, scene: SoleScene, shots: list[int], render: Callable[[list[int]], list[RenderedPair]]
    ) -> list[RenderedPair]:
        """The `shots` of a scene, loaded, and the missing ones made by one `render(missing)` call and stored."""
        pairs = {shot: _load(self._path(scene, shot)) for shot in shots}
        missing = [shot for shot, pair in pairs.items() if pair is None]
        self.hits += len(shots) - len(missing)
        self.misses += len(missing)
        if missing:
            for shot, pair in zip(missing, render(missing), strict=True):
                _store(self._path(scene, shot), pair)
                pairs[shot] = pair
        return [p for p in (pairs[shot] for shot in shots) if p is not None]

    def _path(self, scene: SoleScene, shot: int) -> Path:
        return self.directory / f"{scene_key(scene, shot)}.npz"

    def _get(self, scene: SoleScene, shot: int) -> RenderedPair:
        """The scene with its sole (shot 0), loaded or rendered and stored."""
        path = self._path(scene, shot)
        pair = _load(path)
        if pair is not None:
            self.hits += 1
            return pair
        self.misses += 1
        pair = scene.render()
        _store(path, pair)
        return pair


def _load(path: Path) -> RenderedPair | None:
    try:
        with np.load(path) as data:
            return RenderedPair(data["left"], data["right"], data["depth_left"], data["sole_mask_left"])
    except (
        OSError,
        KeyError,
        ValueError,
        EOFError,
        zipfile.BadZipFile,
    ):  # absent, or cut short by a killed writer: render again
        return None


def _store(path: Path, pair: RenderedPair) -> None:
    handle, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as out:
            np.savez_compressed(
                out,
                left=pair.left,
                right=pair.right,
                depth_left=pair.depth_left,
                sole_mask_left=pair.sole_mask_left,
            )
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
