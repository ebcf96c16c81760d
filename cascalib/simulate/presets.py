"""Named scenario presets: a realistic scenario matrix for tests and benchmarks.

``PRESETS[name]`` is a :class:`~cascalib.simulate.scene.SceneConfig` whose ``description`` says
in one line what it is for; :func:`preset` returns a copy (so callers can change it freely).
``cascalib simulate --list`` prints them.

=================  ======  =======  ==========  ===================  ===========================
preset             cams    persons  area (m)    frame rates          what it stresses
=================  ======  =======  ==========  ===================  ===========================
paper_single_view  1       5        8 x 8       30                   stage I as in the supplement
lab_ring           6       3        5 x 5       30                   the easy indoor case
terrace            4       5        10 x 10     25                   EPFL-terrace-like outdoor rig
periodic           4       3        6 x 6       30                   circles: ambiguous sync
crowd              4       15       12 x 12     25                   occlusion, ids, false hits
security           4       6        15 x 15     25 / 30, drift       steep views, distortion
sports             6       12       40 x 20     50 / 60              far, small people
phones             4       3        6 x 6       30 / 60 / 29.97      portrait, drift, late start
one_spot           4       1        1 x 1       60, synchronised     one person in one spot, 12 s
desk               4       1        1 x 1       30, synchronised     upper bodies close up, barrel
gait               3       1        6 x 1       30                   one walker back and forth, 65 s
horizontal         4       3        6 x 6       30                   level cameras: ground unseen
short_clip         4       3        3 x 3       30                   12 s, people standing, turning
fisheye_webcam     4       2        3 x 3       30                   k1 about -0.34, full bodies
mixed_rates        4       4        10 x 10     30 / 25 / 30 / 29.97 non-integer rate ratios
clean              4       4        10 x 10     25                   perfect detector (tests)
=================  ======  =======  ==========  ===================  ===========================

The single-view protocol itself (ankle/shoulder pairs, the supplement's three sweeps) is
:mod:`cascalib.simulate.paper_protocol`.
"""

from __future__ import annotations

from cascalib.errors import InputError
from cascalib.simulate.detector import DetectorConfig
from cascalib.simulate.people import PeopleConfig
from cascalib.simulate.rigs import RIG_PRESETS, RigConfig
from cascalib.simulate.scene import SceneConfig
from cascalib.simulate.timing import STANDARD_FPS, TimingConfig

__all__ = ["PRESETS", "preset", "REALISTIC_DETECTOR"]

#: A detector with the imperfections of a good off-the-shelf model (HRNet/ViTPose class).
REALISTIC_DETECTOR = DetectorConfig(
    noise_px=1.0, noise_rel=0.008, noise_corr=0.5, outlier_rate=0.01, miss_rate=0.02,
    swap_rate=0.005, occlusion=0.6, min_height_px=30, false_positive_rate=0.05)


def _rig(name: str, **changes: object) -> RigConfig:
    return RIG_PRESETS[name].model_copy(update=changes)


PRESETS: dict[str, SceneConfig] = {
    "paper_single_view": SceneConfig(
        description="Supplement's single-view protocol as a scene: one 1920x1080 camera, "
        "f=960 (90 deg), 0.5 px noise, heights N(1.7, 0.1)",
        duration_s=30,
        people=PeopleConfig(n_persons=5, height_sd=0.1, area=(8, 8)),
        rig=RigConfig(n_cameras=1, distance_range=(5, 7), height_range=(1.5, 4.0),
                      fov_range_deg=(90, 90), image_sizes=((1920, 1080),),
                      principal_offset=0.0, roll_sd_deg=5.0, target_jitter=0.1),
        detector=DetectorConfig(noise_px=0.5, noise_rel=0.0, confidence=False)),
    "lab_ring": SceneConfig(
        description="Indoor lab: 6 cameras 2-3 m high in a ring 4-6 m out, 3 people on 5x5 m, "
        "30 fps, offsets up to 3 s",
        duration_s=40,
        people=PeopleConfig(n_persons=3, area=(5, 5)),
        rig=_rig("lab_ring"),
        timing=TimingConfig(fps=(30.0,), max_offset_s=3.0),
        detector=REALISTIC_DETECTOR),
    "terrace": SceneConfig(
        description="Outdoor terrace (EPFL-like): 4 cameras 2-3 m high around 10x10 m, "
        "5 people, 25 fps, offsets up to 3 s",
        duration_s=60,
        people=PeopleConfig(n_persons=5, area=(10, 10)),
        rig=_rig("terrace"),
        timing=TimingConfig(fps=(25.0,), max_offset_s=3.0),
        detector=REALISTIC_DETECTOR),
    "periodic": SceneConfig(
        description="Failure case of the paper's sync: 3 people walking in circles at constant "
        "speed, 4 lab cameras",
        duration_s=40,
        people=PeopleConfig(n_persons=3, area=(6, 6), periodic=True, pause_prob=0.0),
        rig=_rig("lab_ring", n_cameras=4),
        timing=TimingConfig(fps=(30.0,), max_offset_s=3.0),
        detector=REALISTIC_DETECTOR),
    "crowd": SceneConfig(
        description="15 people on 12x12 m: occlusions, id switches, shuffled slots, "
        "false positives; 4 terrace cameras",
        duration_s=40,
        people=PeopleConfig(n_persons=15, area=(12, 12)),
        rig=_rig("terrace", distance_range=(8.0, 10.0)),
        timing=TimingConfig(fps=(25.0,), max_offset_s=3.0),
        detector=REALISTIC_DETECTOR.model_copy(update={
            "occlusion": 0.8, "false_positive_rate": 0.2, "track_ids": "per_camera",
            "id_switch": 0.3, "shuffle_slots": True})),
    "security": SceneConfig(
        description="High security cameras: 4 cameras 6-10 m up looking steeply down on "
        "15x15 m, wide lenses with barrel distortion, 6 people",
        duration_s=60,
        people=PeopleConfig(n_persons=6, area=(15, 15)),
        rig=_rig("security"),
        timing=TimingConfig(fps=(25.0, 30.0), fps_in_turn=True, max_offset_s=5.0, drift_sd=2e-5),
        detector=REALISTIC_DETECTOR),
    "sports": SceneConfig(
        description="Sports field 40x20 m: 6 cameras 8-15 m high on both long sides, "
        "12 people, 50/60 fps",
        duration_s=40,
        people=PeopleConfig(n_persons=12, area=(40, 20), speed_range=(1.0, 2.0)),
        rig=_rig("sports"),
        timing=TimingConfig(fps=(50.0, 60.0), fps_in_turn=True, max_offset_s=3.0),
        detector=REALISTIC_DETECTOR.model_copy(update={"min_height_px": 40})),
    "phones": SceneConfig(
        description="Phones on tripods: portrait and landscape, distortion, mixed 29.97/30/60 "
        "fps with drift, late starts and early stops",
        duration_s=60,
        people=PeopleConfig(n_persons=3, area=(6, 6)),
        rig=_rig("phones"),
        timing=TimingConfig(fps=(30.0, 60.0, STANDARD_FPS[1]), fps_in_turn=True,
                            max_offset_s=5.0,
                            drift_sd=5e-5, late_start_prob=0.3, early_stop_prob=0.3,
                            late_max_s=8.0),
        detector=REALISTIC_DETECTOR),
    "one_spot": SceneConfig(
        description="One person turning and stepping in one spot for 12 s, seen by 4 portrait "
        "cameras nearly level at 1.6-2.0 m, 60 fps, synchronised (Pose2Sim's demo)",
        duration_s=12,
        people=PeopleConfig(n_persons=1, area=(1.0, 1.0), speed_range=(0.2, 0.4),
                            pause_prob=0.9, turn_prob=1.0, walk_mean_s=1.0),
        rig=RigConfig(n_cameras=4, height_range=(1.6, 2.0), distance_range=(3.0, 5.0),
                      target_height=1.0, fov_range_deg=(55, 70), image_sizes=((1920, 1080),),
                      portrait_prob=1.0),
        timing=TimingConfig(fps=(60.0,), max_offset_s=0.0),
        detector=REALISTIC_DETECTOR),
    "desk": SceneConfig(
        description="One person in one spot 1.2-1.8 m from 4 webcams with barrel distortion: "
        "the legs fall outside the images; 30 fps, 9 s, synchronised (caliscope's session)",
        duration_s=9,
        people=PeopleConfig(n_persons=1, area=(0.6, 0.6), speed_range=(0.1, 0.2),
                            pause_prob=1.0, turn_prob=0.5, walk_mean_s=0.5, actions=()),
        rig=RigConfig(n_cameras=4, height_range=(1.3, 1.7), distance_range=(1.2, 1.8),
                      target_height=1.35, fov_range_deg=(70, 90), image_sizes=((1280, 720),),
                      radial_distortion=0.3, roll_sd_deg=3.0),
        timing=TimingConfig(fps=(30.0,), max_offset_s=0.0),
        detector=REALISTIC_DETECTOR),
    "gait": SceneConfig(
        description="A gait recording: one person walking back and forth along 6 m for 65 s, "
        "3 portrait phones 480x640 at 1.0-1.5 m, 30 fps, unknown offsets",
        duration_s=65,
        people=PeopleConfig(n_persons=1, area=(6.0, 1.0), curviness=0.0, pause_prob=0.2,
                            pause_range_s=(0.5, 2.0), action_prob=0.0, walk_mean_s=6.0),
        rig=RigConfig(n_cameras=3, height_range=(1.0, 1.5), distance_range=(4.0, 6.0),
                      azimuth_jitter_deg=25, target_jitter=0.05, fov_range_deg=(60, 75),
                      image_sizes=((640, 480),), portrait_prob=1.0, roll_sd_deg=2.0),
        timing=TimingConfig(fps=(30.0,), max_offset_s=3.0),
        detector=REALISTIC_DETECTOR),
    "horizontal": SceneConfig(
        description="Cameras nearly level (pitch 0-3 deg down, 1.1-1.5 m high, 7-9 m out): "
        "the ground plane is seen edge-on; 3 people, 30 fps, offsets up to 3 s",
        duration_s=40,
        people=PeopleConfig(n_persons=3, area=(6, 6)),
        rig=RigConfig(n_cameras=4, height_range=(1.1, 1.5), distance_range=(7.0, 9.0),
                      target_height=1.05, target_jitter=0.05, fov_range_deg=(55, 75),
                      image_sizes=((1920, 1080),), roll_sd_deg=1.0),
        timing=TimingConfig(fps=(30.0,), max_offset_s=3.0),
        detector=REALISTIC_DETECTOR),
    "short_clip": SceneConfig(
        description="A 12 s clip: 3 people mostly standing and turning in place on 3x3 m, "
        "4 cameras at 1.6-2.2 m, 30 fps, offsets up to 1 s",
        duration_s=12,
        people=PeopleConfig(n_persons=3, area=(3.0, 3.0), speed_range=(0.3, 0.6),
                            pause_prob=0.9, turn_prob=1.0, walk_mean_s=1.0,
                            pause_range_s=(1.5, 4.0)),
        rig=RigConfig(n_cameras=4, height_range=(1.6, 2.2), distance_range=(4.0, 5.5),
                      fov_range_deg=(55, 75), image_sizes=((1920, 1080), (1280, 720))),
        timing=TimingConfig(fps=(30.0,), max_offset_s=1.0),
        detector=REALISTIC_DETECTOR),
    "fisheye_webcam": SceneConfig(
        description="4 wide webcams 1280x720 with strong barrel distortion (k1 -0.31 to -0.36, "
        "caliscope's), 3.5-4.5 m from the middle of 3x3 m where 2 people walk, full bodies, 30 fps",
        duration_s=30,
        people=PeopleConfig(n_persons=2, area=(3.0, 3.0), speed_range=(0.6, 1.2)),
        rig=RigConfig(n_cameras=4, height_range=(1.6, 2.2), distance_range=(3.5, 4.5),
                      target_height=0.9, fov_range_deg=(80, 95), image_sizes=((1280, 720),),
                      radial_distortion=0.36, radial_distortion_min=0.86, roll_sd_deg=2.0),
        timing=TimingConfig(fps=(30.0,), max_offset_s=2.0),
        detector=REALISTIC_DETECTOR),
    "mixed_rates": SceneConfig(
        description="Terrace rig at 30 / 25 / 30 / 29.97 fps in turn (rate ratios that are "
        "not whole numbers), 4 people, offsets up to 3 s",
        duration_s=40,
        people=PeopleConfig(n_persons=4, area=(10, 10)),
        rig=_rig("terrace"),
        timing=TimingConfig(fps=(30.0, 25.0, 30.0, STANDARD_FPS[1]), fps_in_turn=True,
                            max_offset_s=3.0),
        detector=REALISTIC_DETECTOR),
    "clean": SceneConfig(
        description="Terrace rig with a perfect detector (projected truth): for tests",
        duration_s=30,
        people=PeopleConfig(n_persons=4, area=(10, 10)),
        rig=_rig("terrace"),
        timing=TimingConfig(fps=(25.0,), max_offset_s=3.0),
        detector=DetectorConfig.clean()),
}


def preset(name: str) -> SceneConfig:
    """A copy of the preset ``name``.

    Raises
    ------
    InputError
        For an unknown name (the message lists the presets).
    """
    try:
        return PRESETS[name].model_copy(deep=True)
    except KeyError:
        raise InputError(f"unknown simulation preset {name!r}; presets: "
                         f"{', '.join(PRESETS)}", field="preset") from None
