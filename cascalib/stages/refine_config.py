"""Configuration of stage V, the joint camera refinement (bundle adjustment)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["DEFAULT_JOINTS", "RefineConfig"]

#: Joints used in the bundle adjustment. The paper (sec. "Joint Camera Refinement") leaves out head
#: and arm keypoints because of their motion and self-occlusion; with per-keypoint robust kernels
#: and confidence weights we keep arms and head top (the head top carries the height prior) and
#: only drop eyes and ears, whose tiny baseline makes them nearly useless and which swap sides.
DEFAULT_JOINTS: tuple[str, ...] = (
    "nose", "head_top", "neck", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "mid_hip", "left_hip", "right_hip", "left_knee", "right_knee",
    "left_ankle", "right_ankle", "left_heel", "right_heel", "left_big_toe", "right_big_toe",
)  # fmt: skip


#: Height of the head keypoints above the ground as a fraction of stature, standing (Drillis &
#: Contini 1966: vertex 1.0, eyes 0.936; ears and nose from the same tables, as in
#: cascalib.simulate's body model). The metric scale comes from the first of these the detector
#: gives: COCO-17 and most 17-joint detectors have no head top, only the face points.
HEAD_HEIGHT_FRACTIONS: dict[str, float] = {
    "head_top": 1.0, "left_eye": 0.936, "right_eye": 0.936, "left_ear": 0.928,
    "right_ear": 0.928, "nose": 0.908,
}


class RefineConfig(BaseModel):
    """Stage V settings. Units: pixels (px), metres (m), reference frames, degrees (deg)."""

    model_config = ConfigDict(extra="forbid")

    # -- problem size ----------------------------------------------------------------------------
    joints: tuple[str, ...] = Field(
        DEFAULT_JOINTS, description="Canonical joints in the graph. The paper uses ankles to "
        "shoulders only (Joint Camera Refinement); see DEFAULT_JOINTS for why we keep more.")
    max_groups: int = Field(
        240, ge=10, description="Person-frames selected for the graph (frame selection budget). "
        "The paper keeps the top-k most confident poses; the time of the solve grows with this, "
        "not with the sequence length.")
    intrinsics_groups: int = Field(
        2400, ge=10, description="Person-frames of the principal-point pass (at least; see "
        "intrinsics_groups_per_person). The principal point "
        "trades against the camera's rotation to first order (only the perspective across the "
        "image tells them apart, and on a ring of cameras hardly at all), so it needs more data "
        "than the pose. Measured on 9 simulated 40 s scenes (terrace, lab ring, periodic; seeds "
        "0-2), median / mean / max relative rotation: 1200 -> 0.37 / 0.47 / 1.73 deg, 2400 -> "
        "0.28 / 0.41 / 1.24, 3600 -> 0.36 / 0.45 / 1.25 (an earlier version: 240 -> mean 0.69, "
        "max 3.52). 2400 instead of 1200 adds about 1 s to Stage V on 4 cameras x 3000 frames x "
        "5 persons. The pass's first solve on fewer person-frames (600 or 1200; its update, on "
        "persons associated anew, on all of them), measured on 24 simulated 40 s whole-cascade "
        "scenes (terrace, lab ring, crowd, periodic; seeds 0-5): mean of the median relative "
        "rotations 0.228 -> 0.250 / 0.261 deg, scenes meeting median <= 0.3 / max <= 1 deg "
        "18 -> 16 / 16 (the first solve took 3.8 s of Stage V's 22 s on 4 x 3000 x 5). Not "
        "taken. 3600 again, on the same scenes: terrace mean of medians 0.215 -> 0.200 deg (four "
        "of six better by 0.02-0.07, one 0.10 worse: within the scatter), lab ring and periodic "
        "unchanged (their 40 s hold too few usable person-frames: the pass leaves a fifth out), "
        "crowds not concerned (intrinsics_groups_per_person). Not taken.")
    intrinsics_groups_per_person: int = Field(
        450, ge=0, description="Person-frames of the principal-point pass per person in view "
        "(the rounds' associated persons per reference time), where that is more than "
        "intrinsics_groups, up to intrinsics_groups_max. A crowd offers more person-frames, and "
        "each tells less (occluded, partly seen, farther). Scenes with at most 5 persons in "
        "view stay at intrinsics_groups (4 cameras x 3000 frames x 5 persons: 5.0 per time, "
        "2400 person-frames).")
    intrinsics_groups_max: int = Field(
        4800, ge=10, description="Most person-frames of the principal-point pass (see "
        "intrinsics_groups_per_person). Measured on the crowd preset (15 persons, 14 in view "
        "at a time), 40 s whole-cascade scenes, seeds 0-5, two runs each (refine's rng 0 and "
        "1), median relative rotation: 2400 -> 4800 person-frames, mean 0.403 -> 0.276 deg, "
        "runs meeting median <= 0.3 / max <= 1 deg 3 -> 8 of 12, worst max 1.17 -> 0.82 deg; "
        "about 4000 (rng 0): mean 0.359, 4 of 6. Their Stage V CPU time rose by about 19 %. "
        "6400 (the crowds' 450 per person in view), later, rng 0: mean 0.264 -> 0.292 deg, "
        "scenes meeting the targets 4 -> 3 of 6, worst max 0.53 -> 0.69 deg. Not taken.")
    distortion_groups: int = Field(
        240, ge=10, description="Person-frames of the lens-distortion pass (its principal point "
        "is held where the principal-point pass put it).")
    spread_groups: int = Field(
        240, ge=10, description="Most person-frames in each half of the split-half check of the "
        "principal point (the uncertainty the quality report gives it).")
    spread_iterations: int = Field(
        2, ge=1, description="Levenberg-Marquardt iterations of each half of that split-half "
        "check. Both halves start from the rounds' cameras: stopped too early, they stay "
        "nearer that common start and their distance understates the principal point's error.")
    n_rounds: int | None = Field(
        None, ge=1, description="Solve / re-associate rounds (outlier rejection by "
        "re-association; each also updates the clocks and bone lengths). None: 2 when the "
        "principal-point pass follows (it re-solves every camera on intrinsics_groups "
        "person-frames), else 3. Measured on 9 simulated 40 s scenes (terrace, lab ring, "
        "periodic; seeds 0-2) with that pass, median / mean / max relative rotation: 3 rounds "
        "0.42 / 0.55 / 2.33 deg, 2 rounds 0.34 / 0.47 / 1.72 (offsets max 0.25 frame both), "
        "1 s less per round on 4 cameras x 3000 frames x 5 persons. Without it (principal "
        "point at the image centre), from a start 3 deg / 0.3 m / 0.5 frame off (70 frames): "
        "2 rounds 0.44 deg median, 3 rounds 0.20, 4 rounds 0.09. With None, more rounds "
        "follow while the last one still moved the cameras (max_rounds, round_tolerance_deg, "
        "round_tolerance_focal); a number is exactly that many rounds.")
    max_rounds: int = Field(
        6, ge=1, description="Most rounds when n_rounds is None. From a start 3 deg / 0.3 m / "
        "5 % focal off (bench_refine.py, terrace seed 0) the rounds moved the cameras by up to "
        "3.8, 2.8, 2.1, 0.13, 0.06 deg: 2 rounds left the principal-point pass in a wrong "
        "basin (3.0 deg at the end, 0.44 with more rounds, as from the true rig).")
    round_tolerance_deg: float = Field(
        0.2, gt=0, description="A round that rotated no camera by more (deg, geodesic) and "
        "changed no focal length by more than round_tolerance_focal ends the rounds.")
    round_tolerance_focal: float = Field(
        0.01, gt=0, description="Relative focal change of the same test.")
    round_frames: int = Field(
        1500, ge=100, description="Reference frames (evenly spread) associated in each round to "
        "choose the graph's person-frames from; every frame is reconstructed at the end.")
    max_iterations: int = Field(40, ge=1, description="Levenberg-Marquardt iterations per solve.")
    relative_tolerance: float = Field(
        1e-4, gt=0, description="LM stops when the error drops by less than this fraction; the "
        "graduated stages and rounds that follow make a tighter stop wasted time.")
    lambda_lower_bound: float = Field(
        1e-3, ge=0, description="Levenberg-Marquardt never damps less than this. Below it the "
        "step does not change (the graph's Hessian diagonal is >= 1e3 in pixel units), but after "
        "a run of good steps gtsam's default (0) let the damping fall to 1e-10, and one failed "
        "step then took 12 trials to climb back (measured: a 2.5 s distortion pass, 1.5 s with "
        "this bound, same result).")
    pass_solver: Literal["gauss-newton", "levenberg-marquardt"] = Field(
        "gauss-newton", description="Solver of the principal-point pass, its updates and its "
        "split-half check, which start from solved cameras: Gauss-Newton takes one linear solve "
        "per iteration (Levenberg-Marquardt also copies the linear system to damp it, and may "
        "try several dampings); if its steps do not lower the error, Levenberg-Marquardt solves "
        "instead. The rounds and the distortion pass always use Levenberg-Marquardt. Measured "
        "on 4 cameras x 3000 frames x 5 persons (3 alternating runs each): the 2400-person-frame "
        "pass 1.68-1.93 -> 1.27-1.34 s, all of stage V's solves 6.5-8.2 -> 5.2-6.7 s; on 24 "
        "simulated 40 s whole-cascade scenes (terrace, lab ring, crowd, periodic; seeds 0-5) "
        "18 of 24 meet median <= 0.3 / max <= 1 deg either way, mean of the medians 0.234 -> "
        "0.233 deg, worst offset 0.103 -> 0.103 frame; 23 scenes moved by < 0.002 deg, crowd "
        "seed 0 median 0.393 -> 0.363, max 0.515 -> 0.570 deg, focal 0.30 -> 0.47 %.")
    schur: bool = Field(
        True, description="Eliminate the 3D points first (the Schur complement on the points), "
        "then the cameras. Measured on the principal-point pass of 4 cameras x 3000 frames x 5 "
        "persons: 1.1 s against 2.0 s with gtsam's SfmLevenbergMarquardtOptimizer and 2.5 s "
        "for gtsam's COLAMD ordering alone (used when False).")

    # -- measurement model -------------------------------------------------------------------------
    sigma_px: float = Field(
        2.0, gt=0, description="Keypoint noise (px) at confidence 1; scaled by 1/sqrt(conf).")
    size_noise: bool = Field(
        True, description="Weigh each view's keypoints by a noise that grows with the person's "
        "size in the image, sigma^2 = a + b h^2 fitted to the triangulation residuals "
        "(keypoint_noise). Measured on the crowd preset from the true rig: relative rotations "
        "0.75 / 1.10 deg (median / max) with one noise level for every person (off), 0.17 / 0.23 "
        "with it.")
    min_confidence: float = Field(0.1, ge=0, le=1, description="Keypoints below are ignored.")
    robust: Literal["huber", "cauchy"] = Field(
        "huber", description="Robust kernel of the reprojection factors (the paper uses none). "
        "Measured, Huber (robust_k 1.345) -> Cauchy (robust_k 2.385, its 95 % value): on 24 "
        "simulated 40 s whole-cascade scenes (terrace, lab ring, crowd, periodic; seeds 0-5) "
        "mean of median relative rotations 0.239 -> 0.223 deg, scenes meeting median <= 0.3 and "
        "max <= 1 deg 18 -> 19, sum of the scenes' worst offsets 0.712 -> 0.803 frame; on "
        "bench_refine.py's accuracy table (terrace, lab ring, crowd; seeds 0-2, from 3-5 deg off) "
        "0.263 -> 0.256 deg, crowd maxima 0.48 / 0.76 / 0.55 -> 0.68 / 0.33 / 0.75. Single "
        "scenes moved by up to 0.24 deg either way: no difference these 33 scenes can tell "
        "from their scatter (about 0.014 deg on the mean); not taken.")
    robust_k: float = Field(
        1.345, gt=0, description="Kernel threshold in standard deviations (Huber's 95 % value).")

    # -- body priors -------------------------------------------------------------------------------
    height_sd: float = Field(
        0.07, gt=0, description="Population sd of adult height (m); the paper assumes one "
        "height of 1.70 m (supplement, height error L_h).")
    head_top_fraction: float = Field(
        0.97, gt=0.8, le=1.1, description="Height of the head_top keypoint as a fraction of "
        "stature while walking (knee flexion and a keypoint just below the vertex: 0.95-0.99 "
        "in cascalib.simulate's gait model). Other head points (when the detector has no head "
        "top) sit lower by their standing fraction (HEAD_HEIGHT_FRACTIONS) with the same dip.")

    ankle_height: float = Field(
        0.07, ge=0, le=0.2, description="Height of the ankle joint above the floor (m) when "
        "the foot is in stance: 0.039 of stature (Winter 2009); the paper (L_p) uses 0.")
    ground_sigma_m: float = Field(0.03, gt=0, description="Stance-ankle height noise (m).")
    ground_effective_n: int = Field(
        10, ge=1, description="The stance-ankle priors together weigh as this many ankles. "
        "They only fix the plane (z, roll, pitch); at full weight they would shrink the scene, "
        "since a smaller scale shrinks the spread of ankle heights at no reprojection cost.")
    stance_tolerance_m: float = Field(
        0.03, gt=0, description="A foot is in stance when its ankle is at most this much higher "
        "than the other ankle (m).")
    use_bones: bool = Field(
        True, description="Left/right symmetry and constant bone length over each track, as "
        "RangeFactor3 terms to per-track medians triangulated with the previous round's cameras "
        "(paper: L_left,right); tracks are cut where the person's size jumps (a swap of two "
        "people) and pieces of one size rejoined (person_size.split_by_size).")
    bone_sigma_m: float = Field(0.015, gt=0, description="Bone-length noise (m).")
    upright_sigma_m: float = Field(
        0.02, ge=0, description="Upright torsos in the intrinsics passes: the neck of a standing "
        "or walking person is above the mid-hip, ahead of it by the walking lean (fitted to "
        "each graph's persons, torso_lean), with this horizontal sd (m) in a Huber kernel; 0: "
        "off. It settles part of the principal point's trade-off with the rotation (terrace "
        "seed 0 from the true rig: 0.94 -> 0.35 deg). Not in the rounds: their principal points "
        "sit at the image centre, and their rotations must absorb that.")

    # -- gauge -------------------------------------------------------------------------------------
    gauge_yaw_sigma_deg: float = Field(
        0.01, gt=0, description="Prior on the reference camera's yaw (fixes the world yaw).")
    gauge_xy_sigma_m: float = Field(
        0.001, gt=0, description="Prior on the reference camera's x, y (fixes the world origin).")
    gauge_tilt_sigma_deg: float = Field(
        10.0, gt=0, description="Loose prior on the reference camera's tilt and roll.")
    gauge_z_sigma_m: float = Field(1.0, gt=0, description="Loose prior on its height (m).")

    # -- association -------------------------------------------------------------------------------
    gate_m: float = Field(
        1.5, gt=0, description="Ground distance gate (m) of the first association, sized for "
        "the errors stages II-IV leave (~3 deg, ~0.3 m).")
    align_ground: int = Field(
        2, ge=0, description="First round: rounds of per-camera affine warps of the ground "
        "positions onto the other cameras' before re-clustering (absorbs the metres of ground "
        "error a few degrees of tilt cause at shallow viewing angles).")
    gate_refined_m: float = Field(0.6, gt=0, description="Gate after the first solve (m).")
    consistency: float = Field(
        0.3, gt=0, description="First-round gate of a view's median reprojection error after "
        "triangulation, as a fraction of the person's size in the image.")
    consistency_refined: float = Field(0.08, gt=0, description="The same gate after a solve.")
    n_time_bins: int = Field(60, ge=1, description="Time bins of the frame selection.")
    floor_cell_m: float = Field(1.0, gt=0, description="Floor cell of the frame selection (m).")
    image_grid: int = Field(4, ge=1, description="Image grid (n x n) of the frame selection.")

    # -- time --------------------------------------------------------------------------------------
    refine_time: bool = Field(
        True, description="Refine each camera's time offset to sub-frame accuracy between "
        "rounds by interpolating its 2D tracks (and its frame-rate ratio: time_rates).")
    time_rates: bool = Field(
        True, description="Refine each camera's frame-rate ratio with its offset (else stage "
        "III's is kept). Held at stage III's rate, the offset settles where the middle of the "
        "recording agrees and the rate's error shows as an offset error at frame 0. The rate "
        "is shrunk toward stage III's by its block-scatter standard error (time_rate_sd), so a "
        "rate the data cannot pin stays put. Measured with bench_sync.py's 24 scenes (terrace, "
        "lab ring, crowd, periodic, with and without stage-I errors, seeds 0-2; 881 frames, "
        "offsets up to half the recording, 25/30 fps, drift), Stage V offset |error| at frame "
        "0 over 84 cameras, off -> on: median 0.075 -> 0.038 frame, cameras > 0.1 frame 29 -> "
        "14, max 0.284 -> 0.276 (terrace 0.035 / 0.227 -> 0.031 / 0.189 median / max, lab "
        "ring 0.084 / 0.284 -> 0.053 / 0.190, crowd 0.081 / 0.223 -> 0.044 / 0.276, periodic "
        "0.056 / 0.103 -> 0.034 / 0.078); rate error max 0.024 %; relative rotations unchanged "
        "(mean 0.316 -> 0.319, worst 0.78 -> 0.82 deg).")
    time_final_update: bool = Field(
        True, description="One more clock update (time_iterations updates, each kept only if "
        "it lowers the joint error) after the intrinsics passes, which move the geometry after "
        "the rounds' last update. Measured on bench_sync.py's 24 scenes (84 cameras, Stage V "
        "offset |error| at frame 0): max 0.276 -> 0.182 frame, cameras > 0.1 frame 14 -> 10, "
        "median 0.038 -> 0.037; rotations unchanged (no geometry solve follows). Cost: 1.1 s of "
        "CPU on 4 cameras x 3000 frames x 5 persons (its update rejected there), 1.8 s of "
        "Stage V's 20 s on the README example.")
    time_each_round: bool = Field(
        True, description="Update the clocks after every round (else only after the last "
        "round, before the intrinsics passes). Measured on 24 simulated 40 s whole-cascade "
        "scenes (terrace, lab ring, crowd, periodic; seeds 0-5), every round -> last only: "
        "relative rotation mean of medians 0.234 -> 0.227 deg, scenes meeting 0.3 / 1 deg 18 "
        "-> 19 (single scenes moved by up to 0.19 deg either way), worst offset error 0.103 -> "
        "0.128 frame with cameras > 0.1 frame 1 -> 4 scenes, Stage V CPU 772 -> 704 s (-9 %). "
        "Kept on: the offsets are the target it would miss. Remeasured with the clock "
        "search's Cauchy weights (same scenes): mean of medians 0.239 -> 0.246 deg, meeting "
        "18 -> 17, focal worst 0.83 -> 0.94 %, centres worst 4.4 -> 5.4 cm, offsets sum "
        "0.712 -> 0.718 frame, Stage V CPU -14 %; kept on.")
    time_rate_sd: float = Field(
        1e-4, gt=0, description="Prior sd of each camera's relative rate around stage III's (which "
        "is good to about that): the clock search weighs its own rate against it by the scatter "
        "of time blocks of the recording, so that a short recording keeps stage III's rate.")
    time_iterations: int = Field(
        2, ge=1, description="Offset updates (each after a re-association) after each round. "
        "Measured with 1 on 24 simulated 40 s whole-cascade scenes (terrace, lab ring, crowd, "
        "periodic; seeds 0-5): mean of the median relative rotations 0.228 -> 0.258 deg, "
        "scenes meeting median <= 0.3 / max <= 1 deg 18 -> 17, the six crowds 0.264 -> 0.358 "
        "(four worse), the other scenes within 0.01 deg but terrace seed 2 (0.27 -> 0.42) and "
        "lab ring seed 2 (0.11 -> 0.18); one clock update (1.1-1.6 s each on 4 cameras x "
        "3000 frames x 5 persons) less. Not taken.")
    time_settle_frames: float = Field(
        0.02, ge=0, description="A kept clock update that moved no camera's offset by more "
        "(frames) ends that step's updates: the next one would move them less still, and the "
        "joint error that decides on it cannot tell such steps apart (4 x 3000 x 5: the "
        "final step's second update, rejected there, took about 1 s). Measured on 24 "
        "simulated 40 s whole-cascade scenes: 20 identical, 4 changed by at most 0.011 deg; "
        "mean over scenes of the worst offset error 0.0479 -> 0.0486 frame, worst 0.103 -> "
        "0.103. 0 never ends early.")
    time_search_frames: float = Field(
        1.0, gt=0, description="Half-width of the sub-frame offset search (reference frames).")
    time_step_frames: float = Field(
        0.05, gt=0, description="Unused since the offset search solves its normal equation "
        "(to 0.001 frame) instead of scanning a grid; kept so that existing settings load.")
    time_groups: int = Field(
        6000, ge=10, description="Person-frames (a random subset) on which each camera's offset "
        "is searched.")
    time_tie_tolerance: float = Field(
        0.002, ge=0, description="A clock update is kept unless the joint error that checks it "
        "grows by more than this fraction: it is a median of reprojection errors, and an "
        "update it cannot tell from the last is the measurement's to decide. The error is "
        "compared on the same persons at the same times through both clocks; compared on two "
        "associations made anew, as before, which persons each kept moved it by more than a "
        "clock does: on a windowed crowd (bench_sync.py, seed 1) the true clocks scored 0.30 % "
        "worse than a camera 0.175 frame off, with the true rig, and paired 0.56 % better. "
        "Measured on 24 simulated 40 s whole-cascade scenes (terrace, lab ring, crowd, "
        "periodic; seeds 0-5), unpaired 0.002 -> paired 0.002 / paired 0: scenes meeting "
        "median <= 0.3 and max <= 1 deg 19 -> 21 / 18, mean of median rotation errors 0.250 "
        "-> 0.236 / 0.229 deg, worst 0.750 -> 0.739 / 0.749, sum of the scenes' worst offset "
        "errors 0.753 -> 0.784 / 0.828 frame (worst 0.066 -> 0.079 / 0.071), CPU +7 / +10 %; "
        "lab ring and periodic came out the same, the crowd scenes moved by up to 0.4 deg "
        "either way. bench_sync.py --refine (84 cameras), unpaired -> paired: terrace, lab ring "
        "and periodic rows the same to 0.007 frame; the windowed crowds' worst offset error "
        "0.175 -> 0.121 frame without stage-I errors and 0.096 -> 0.162 with them, their worst "
        "relative rotation 1.37 -> 1.63 and 1.11 -> 1.04 deg. The crowds' clocks are as good "
        "as the clock search on them (about 0.1 frame and 0.02 % in rate, also with the true "
        "intrinsics held and the rotations 0.01 deg right), which the check cannot improve; "
        "with its Cauchy weights since (:mod:`cascalib.stages.time_refine`), 0.114 and 0.091 "
        "frame.")
    time_check_frames: int = Field(
        800, ge=50, description="Reference frames (evenly spread) on which an offset update is "
        "checked against the joint triangulation error of all cameras.")

    # -- intrinsics --------------------------------------------------------------------------------
    distortion: Literal["auto", "never", "always"] = Field(
        "auto", description="Lens pass with the focal (square pixels), k1, k2, p1, p2 "
        "(Cal3DS2), the principal point held (distortion_pp_sigma_px), after the rounds "
        "(lens_first) and at the end: 'auto' keeps it only if it lowers the held-out "
        "reprojection error measurably (distortion_min_gain).")
    lens_first: bool = Field(
        True, description="Run the lens-distortion pass right after the rounds, before the "
        "principal-point pass, instead of at the end. Where it is kept (distortion 'auto': by "
        "distortion_min_gain) every later solve holds the lens it found (keypoints undistorted "
        "with it, focal and principal point still free), and the lens pass runs again at the "
        "final principal points (kept unless held-out persons reproject worse); where it is "
        "not, no lens is looked for at the end either. A lens the start cameras carry counts as "
        "found: the rounds hold it and the pass re-estimates it (kept unless worse). Off, "
        "the rounds and the principal-point pass fit a pinhole to a distorted lens and the "
        "principal points take up the distortion. Measured on the simulator's whole-cascade "
        "scenes (60 s, seeds 0-2; Stage V from the same stage IV rigs), median / max relative "
        "rotation, off -> on: "
        "security 2.43 / 4.79 -> 0.63 / 1.05, 4.21 / 6.37 -> 0.77 / 1.28, 3.01 / 4.62 -> "
        "0.37 / 0.63 deg (stage IV left 0.86 / 1.29, 0.96 / 1.33, 0.52 / 1.03), focal max "
        "3.44 / 3.15 / 1.24 -> 0.42 / 0.71 / 0.71 %, Stage V 43 / 40 / 37 -> 29 / 31 / 29 s "
        "(no rerun of the principal-point pass); phones 1.72 / 3.22 -> 1.13 / 1.73, 1.34 / "
        "1.66 -> 1.05 / 1.91, 2.13 / 3.68 -> 1.77 / 2.65 deg (from a start 3 deg off the true "
        "rig, bench_refine.py --table distortion: phones 1.78 / 1.42 / 1.89 -> 1.21 / 2.06 / "
        "2.05 deg median, the early pass splitting a weak lens between k1 and k2 on seed 1; "
        "security 2.53 / 4.41 / 2.20 -> 0.79 / 1.53 / 2.16). On 24 distortion-free scenes "
        "(terrace, lab ring, crowd, periodic; 40 s, seeds 0-5) the pass was kept on none "
        "(held-out gains -0.2 to +0.3 %) and rotations, focal lengths and centres came out "
        "identical; the crowds' last clock update drew other random subsets (mean of the "
        "worst offset errors 0.0211 -> 0.0214 frame, worst 0.048 both), Stage V CPU 682 -> "
        "686 s over the 24 (the lens pass moved, none added).")
    distortion_pp_sigma_px: float = Field(
        0.5, gt=0, description="Prior sd (px) of the principal point in the distortion pass, "
        "around where the principal-point pass put it. Freed as well, it trades against the "
        "rotation and the lens terms: on the phones preset the focal and camera centres then "
        "came out worse than with no distortion model at all.")
    distortion_min_gain: float = Field(
        0.02, ge=0, description="Relative drop of the held-out median reprojection error that "
        "'auto' requires to keep the distortion model. Measured (bench_refine.py, 60 s scenes): "
        "-0.2 and 0.0 % on distortion-free rigs (terrace, lab ring), 2.6-3.5 % on the phones "
        "(k1 -0.04 .. -0.11), 15 % on the security cameras.")
    principal_point: Literal["auto", "never", "always"] = Field(
        "auto", description="Pass with the principal point free (Cal3_S2, fx = fy): 'auto' "
        "keeps it unless it raises the held-out reprojection error (if it does, it is judged "
        "again after its updates, principal_point_updates). A principal point 2 % off the centre "
        "tilts a wide-angle camera by about a degree if it is held fixed.")
    principal_point_iterations: int = Field(
        1, ge=1, description="Levenberg-Marquardt iterations of the principal-point pass. "
        "Measured (terrace, 1200 person-frames): the principal points move by < 0.1 px after "
        "the 4th; the 5th to 10th iterations cost 2.5 s -> 11 s and lower the error by 0.14 %. "
        "The update that follows (principal_point_updates) starts from the pass, on persons "
        "associated anew with its cameras (principal_point_reassociate): measured on 24 "
        "simulated 40 s whole-cascade scenes (terrace, lab ring, crowd, periodic; seeds 0-5), "
        "median / mean / worst relative rotation with 3 -> 2 iterations 0.207 / 0.292 / 1.046 "
        "-> 0.209 / 0.293 / 1.046 deg (before the re-association), with 2 -> 1 0.205 / 0.263 / "
        "1.031 -> 0.210 / 0.260 / 0.695 deg (worst max 1.14 -> 1.09, focal worst 1.25 -> 1.11 "
        "%, scenes meeting 0.3 / 1 deg 17 -> 18; single scenes moved by up to 0.34 deg either "
        "way); each iteration of the 2400-person-frame pass costs 1.2-1.5 s on 4 cameras x "
        "3000 frames x 5 persons.")
    principal_point_updates: int = Field(
        1, ge=0, description="The principal-point pass is solved again this many times, each "
        "with the bone-length targets triangulated anew with the previous solve's cameras (the "
        "rounds' targets, from principal points at the image centre, hold the pass near that "
        "start). Measured on 24 simulated 40 s scenes (terrace, lab ring, crowd, periodic; "
        "seeds 0-5, with the upright torsos), median / mean / max relative rotation: 0 -> 0.255 "
        "/ 0.372 / 1.82 deg, 1 -> 0.225 / 0.319 / 1.50 (scenes meeting median <= 0.3 and max "
        "<= 1: 14 -> 16). From the true rig it drifts a little (terrace seed 0: 0.35 -> 0.39). "
        "Each costs one more pass (2-3 s on 4 cameras x 3000 frames x 5 persons).")
    principal_point_update_iterations: int = Field(
        2, ge=1, description="Levenberg-Marquardt iterations of each principal-point update (it "
        "starts from the pass). Measured on the 24 scenes above: 2 instead of 3 gives median / "
        "mean / max 0.22 / 0.32 / 1.52 deg against 0.225 / 0.319 / 1.50, one iteration (about "
        "1 s on 4 cameras x 3000 frames x 5 persons) less. 1 instead of 2 (with a 2-iteration "
        "pass): 0.209 / 0.293 / 1.046 -> 0.238 / 0.302 / 1.090, 18 -> 16 scenes meeting the "
        "targets; not taken.")
    principal_point_rerun_deg: float = Field(
        0.6, ge=0, description="When the principal-point update moved a camera by more than "
        "this (deg, geodesic) from the pass, one more round (association, solve with the "
        "principal points held where the pass put them, clock update) and principal-point "
        "pass follow, again while the update still moves that much (principal_point_reruns "
        "at most). The rounds hold the principal points at the image centre: their "
        "association, clocks and bone targets are made at a geometry off by about what the "
        "update still moves, and in a crowd wrong people join the groups there. inf: never. "
        "Measured on 24 simulated 40 s whole-cascade scenes (terrace, lab ring, crowd, "
        "periodic; seeds 0-5): the update moved the cameras by 0.16-1.04 deg; with 0.6 it "
        "reran on 7 (among them the two crowds worst off), whose rerun updates then moved "
        "0.04-0.28 deg; relative rotation median 0.209 -> 0.213 deg, mean 0.259 -> 0.234, "
        "worst scene 0.695 -> 0.536 (max 1.09 -> 0.75), crowds' mean median 0.383 -> 0.287, "
        "focal worst 1.11 -> 0.59 %, centres worst 5.4 -> 3.0 cm, scenes meeting 0.3 / 1 deg "
        "18 -> 18 (crowd seed 1 in, periodic seed 0 out: 0.293 -> 0.320); of the 7, 5 "
        "improved and 2 lost 0.03 deg; 22 % more time over the 24. Rerunning always (0, one "
        "rerun): median 0.192, mean 0.227, 17 meeting, 78 % more time. 0.4 instead, on the six "
        "crowds with three rngs each (refine's random subsets alone moved a crowd's median by "
        "up to 0.77 deg): mean of the medians 0.310 -> 0.251 deg, runs meeting median <= 0.3 / "
        "max <= 1 deg 9 -> 12 of 18, worst max 1.35 -> 0.70 deg (crowd seed 0 with rng 11: its "
        "update had moved the cameras 0.599 deg, no rerun, 0.91 / 1.35 deg; with it 0.17 / "
        "0.31); 10 runs unchanged, 6 better, 2 within 0.01 deg. On the 18 other scenes (one "
        "rng) it reran on 6: 4 of them lost 0.01-0.07 deg, 2 gained < 0.01 (mean of medians "
        "0.216 -> 0.223, meeting 14 -> 14); the 4 x 3000 x 5 scene's update moves 0.596 deg, "
        "so it would pay "
        "one more round and pass there. Not taken: the crowds have a rule of their own, "
        "principal_point_rerun_persons.")
    principal_point_reruns: int = Field(
        2, ge=0, description="Most reruns of principal_point_rerun_deg. From a start 3 deg / "
        "0.3 m / 5 % focal off the true rig (bench_refine.py, crowd seed 0: the rounds never "
        "settle there, the image-centre principal points are up to 2.9 deg off) the updates "
        "moved the cameras by 1.86, 0.73, 0.47 deg; relative rotation median / max with 0, 1, "
        "2 reruns 1.96 / 2.09, 0.61 / 0.77, 0.24 / 0.31 deg (focal max 2.6, 0.75, 0.24 %). "
        "On the 24 scenes above no second rerun was asked for.")
    principal_point_rerun_persons: int | None = Field(
        10, ge=1, description="A crowd, where the rounds associated at least this many persons "
        "at a reference time (median over the times), gets one rerun of principal_point_"
        "rerun_deg whatever its update moved; further reruns follow that threshold. In a crowd "
        "the rounds' association, made with the principal points at the image centre, joins "
        "wrong persons: associated again with the pass's cameras, 4-13 % of the crowds' "
        "person-frames were grouped differently, 0.4-1.3 % on the lab-ring and periodic "
        "scenes, 1-3 % on five terrace scenes and 23 % on the sixth (the groups' 2D centres "
        "compared, which a clock update also moves): the count of persons tells the crowds "
        "apart more clearly. None: never. Measured on the six simulated 40 s "
        "whole-cascade crowds (15 persons, a median of 15 associated at a time; the terrace, "
        "lab-ring and periodic scenes have 5, 3 and 3, and keep their results) with three "
        "rngs of refine each (cached, 11, 12), median relative rotation: mean 0.310 -> "
        "0.244 deg, runs meeting median <= 0.3 / max <= 1 deg 9 -> 14 of 18, worst max 1.35 "
        "-> 0.73 deg (mean max 0.443 -> 0.361); of the 15 runs it changed (3 had rerun "
        "already) 9 improved by 0.02-0.47 deg and 6 lost 0.01-0.07 (crowd seeds 2 and 5 at "
        "every rng). Rerunning at principal_point_rerun_deg 0.4 instead gave 0.251, 12 of 18 "
        "and 0.70 on the crowds and reran on 6 of the 18 other scenes too, 4 of them worse. "
        "Two forced reruns on 12 of the other scenes: mean of medians 0.200 -> 0.213 deg, 9 "
        "worse (lab ring seed 0 0.221 -> 0.278, terrace seed 2 0.274 -> 0.348, periodic seed "
        "3 0.196 -> 0.271), 3 better (terrace seed 1 0.360 -> 0.312). Cost: one round, its "
        "clock update and the pass, whose crowd-size budget (intrinsics_groups_max) makes it "
        "the dearest step: crowd seed 4's Stage V took 48 -> 82 s CPU (73 s wall).")
    principal_point_reassociate: bool = Field(
        True, description="Before the principal-point update, associate the persons again "
        "with the pass's cameras and choose the update's (and the distortion pass's) "
        "person-frames from that association. The rounds' association came from cameras "
        "whose principal points sat at the image centre, degrees off in rotation where the "
        "principal point is off: its refined gates keep wrong views and drop right ones, "
        "most of all in crowds. Measured on 24 simulated 40 s whole-cascade scenes (terrace, "
        "lab ring, crowd, periodic; seeds 0-5), off -> on: relative rotation median 0.209 -> "
        "0.205 deg, mean 0.293 -> 0.263, worst scene max 1.56 -> 1.14 (crowd seed 0), "
        "crowds' mean median 0.488 -> 0.404 (seed 1: 0.81 -> 0.44), focal worst 1.68 -> "
        "1.25 %, offsets worst 0.125 -> 0.103 frame (mean 0.045 -> 0.047, as with other "
        "random subsets of the clock search: 0.044 in a run with the same geometry); scenes "
        "meeting 0.3 / 1 deg 18 -> 17 (crowd seed 4: 0.292 -> 0.306 deg). Cost: one "
        "association and selection of the rounds' frames, +0.6 s on average in two paired "
        "runs of Stage V on 4 cameras x 3000 frames x 5 persons (18.2 and 20.3 s off, 19.7 "
        "and 20.1 s on; rotation 0.427 / 0.752 -> 0.425 / 0.725 deg).")
    principal_point_sigma: float = Field(
        0.02, gt=0, description="Prior sd of the principal point around the image centre, as a "
        "fraction of the image width. Where the principal points are not estimated "
        "(principal_point 'never', or the pass not kept) the quality report gives them this sd, "
        "and the rotation's sigma includes it: lower it for cameras known to be centred.")
    distortion_sigma: float = Field(0.3, gt=0, description="Prior sd of k1 and k2.")
    tangential_sigma: float = Field(0.01, gt=0, description="Prior sd of p1 and p2.")

    # -- quality -----------------------------------------------------------------------------------
    inlier_px: float = Field(
        8.0, gt=0, description="Reprojection error (px) below which an observation is an inlier.")
    accept_median_px: float = Field(
        4.0, gt=0, description="Largest median reprojection error of an accepted camera.")
    fail_median_px: float = Field(
        15.0, gt=0, description="Median reprojection error above which a camera failed.")
    min_inlier_rate: float = Field(0.6, ge=0, le=1, description="Below: suspicious.")
    fail_inlier_rate: float = Field(0.3, ge=0, le=1, description="Below: failed.")
    min_observations: int = Field(50, ge=0, description="Fewer observations: failed.")
    max_sigma_rotation_deg: float = Field(
        1.0, gt=0, description="Above: suspicious. The calibrated sigma tracks the true error "
        "(0.5-0.9 deg on well-calibrated simulated rigs, several degrees on broken ones), so a "
        "tighter threshold flags good cameras.")
    max_sigma_position_m: float = Field(0.15, gt=0, description="Above: suspicious.")
    max_sigma_focal_rel: float = Field(0.03, gt=0, description="Above: suspicious.")
    time_uncertainty_inflation: float = Field(
        2.0, gt=0, description="The quality report's 1-sigma of a camera's time offset is "
        "sqrt((this * se)^2 + time_uncertainty_floor_frames^2), se the standard error of the "
        "last clock update's measurement (the scatter of its time blocks). Calibrated on the "
        "84 cameras of bench_sync.py's 24 scenes after Stage V (|offset error| at frame 0, "
        "median 0.027 frame): se alone covered 27 % of the errors within 1 sigma and 52 % "
        "within 2; this model 70 % and 95 %, and 71 / 95 % and 69 / 95 % in the halves of "
        "smaller and larger se (3 * se without a floor: 62 / 88 % and 79 / 98 %). Checked on "
        "84 other cameras (24 simulated 40 s whole-cascade scenes, median error 0.021 frame): "
        "74 % within 1 sigma, 90 % within 2, largest error 3.4 sigma. The se ranks the "
        "cameras only loosely (Spearman 0.22 and 0.09 with the error): the floor, errors the "
        "motion's scatter does not show (geometry, detector bias), is most of the sigma "
        "(median 0.03-0.04 frame, largest 0.10-0.15).")
    time_uncertainty_floor_frames: float = Field(
        0.025, ge=0, description="See time_uncertainty_inflation (reference frames).")
    uncertainty_inflation: float = Field(
        3.0, gt=0, description="Factor on the marginal sigmas (after the a-posteriori variance "
        "factor): marginals reflect noise, not model bias (detector bias, body-model error); "
        "calibrated against the measured errors of bench/bench_refine.py.")

    def association_gates(self, *, refined: bool) -> dict[str, float | int]:
        """Keywords of :func:`~cascalib.stages.association.associate` for the rounds: the
        first round's wide gates and ground warps (cameras as stages II-IV left them), or the
        ``refined`` ones (cameras out of a solve)."""
        return {"ankle_height": self.ankle_height,
                "gate_m": self.gate_refined_m if refined else self.gate_m,
                "consistency": self.consistency_refined if refined else self.consistency,
                "align_ground": 0 if refined else self.align_ground}

    def head_height(self, joint: str, height: float) -> float:
        """Height (m) above the ground of head keypoint ``joint`` of a walking person."""
        return (HEAD_HEIGHT_FRACTIONS[joint] + self.head_top_fraction - 1.0) * height
