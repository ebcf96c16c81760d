"""Simulated multi-camera scenes with people, unsynchronised cameras and a detector model.

    >>> from cascalib.simulate import simulate
    >>> scene = simulate("terrace", seed=0)
    >>> [t.camera for t in scene.tracks]
    ['cam0', 'cam1', 'cam2', 'cam3']
    >>> scene.joints3d("cam1").shape[1:] == (len(scene.heights), 26, 3)
    True

Modules: :mod:`.body` (anthropometry), :mod:`.people` (paths, gait, actions), :mod:`.rigs`
(camera rigs), :mod:`.timing` (clocks), :mod:`.detector` (detector model), :mod:`.scene`
(:class:`SceneConfig`, :class:`Scene`, :func:`simulate`), :mod:`.presets`, :mod:`.output`,
:mod:`.paper_protocol` (the supplement's single-view protocol) and :mod:`.plot`.
"""

from cascalib.simulate.detector import DetectorConfig
from cascalib.simulate.people import PeopleConfig
from cascalib.simulate.presets import PRESETS, preset
from cascalib.simulate.rigs import RIG_PRESETS, RigConfig
from cascalib.simulate.scene import Scene, SceneConfig, simulate
from cascalib.simulate.timing import STANDARD_FPS, TimingConfig

__all__ = [
    "PRESETS",
    "RIG_PRESETS",
    "STANDARD_FPS",
    "DetectorConfig",
    "PeopleConfig",
    "RigConfig",
    "Scene",
    "SceneConfig",
    "TimingConfig",
    "preset",
    "simulate",
]
