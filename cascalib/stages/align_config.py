"""Configuration of stages II-IV (ground trajectories, time sync, rotation search, ICP)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["AlignConfig"]


class AlignConfig(BaseModel):
    """Stages II-IV settings. Units: metres (m), reference-camera frames, seconds (s)."""

    model_config = ConfigDict(extra="forbid")

    # -- ground-plane trajectories (paper: "Relating multiple cameras through their ground
    #    planes" and "Filtering") ------------------------------------------------------------------
    foot_height: float = Field(
        0.066, ge=0, description="Height (m) of the ankle midpoint above the stage-I ground "
        "plane when back-projecting feet: 0.039 x 1.70 m (Drillis & Contini). A wrong value "
        "scales each camera's ground view radially, which the similarity alignment absorbs.")
    min_confidence: float = Field(
        0.05, ge=0, le=1, description="Foot joints below this detector confidence are ignored.")
    max_range: float = Field(
        60.0, gt=0, description="Ground points farther (m) from the point below the camera are "
        "dropped: near the horizon one pixel moves them by metres.")
    dbscan_eps: float = Field(
        0.6, gt=0, description="DBSCAN radius (m) of the ground-point outlier filter (paper: "
        "DBSCAN keeping the largest cluster; we keep every cluster above "
        "dbscan_min_cluster_fraction).")
    dbscan_min_samples: int = Field(8, ge=1, description="DBSCAN core-point neighbourhood size.")
    dbscan_min_cluster_fraction: float = Field(
        0.02, ge=0, le=1, description="Clusters holding less than this fraction of the points "
        "are outliers.")
    max_speed: float = Field(
        8.0, gt=0, description="Fastest plausible foot speed (m/s); faster steps split a "
        "tracklet (identity switch or outlier).")
    link_speed: float = Field(
        2.5, gt=0, description="Walking speed (m/s) bounding how far a person moves across a "
        "gap when linking detections without track ids.")
    max_gap_seconds: float = Field(
        0.4, ge=0, description="Longest gap (s) bridged inside one tracklet (occlusions).")
    jump_threshold: float = Field(
        0.5, gt=0, description="A point farther (m) than this from the running median of its "
        "tracklet is an outlier.")
    stance_speed: float = Field(
        0.15, ge=0, description="Ankles are weighted 1 / (v + stance_speed)^2 by their ground "
        "speed v (m/s) so the standing foot dominates: a swinging ankle is off the plane and "
        "back-projects decimetres away, differently per camera. 0 = plain ankle midpoint "
        "(paper).")
    stance_smooth_seconds: float = Field(
        0.0, ge=0, description="Smoothing (s) of the ankle tracks before their speed is taken "
        "for the stance weights (0: none).")
    min_tracklet_frames: int = Field(
        10, ge=2, description="Shorter tracklets are dropped (native frames).")

    # -- time synchronisation (paper: "1D Temporal Search") ------------------------------------
    coarse_rate: float = Field(
        15.0, gt=0, description="Sampling rate (Hz) of the coarse offset search grid; walking "
        "is smooth enough that 15 Hz loses nothing and halves the work at 30 fps.")
    chunk_seconds: float = Field(
        6.0, gt=0, description="Length (s) of the trajectory chunks that vote for offsets.")
    min_overlap_seconds: float = Field(
        1.5, gt=0, description="Least overlap (s) of a chunk with a tracklet of the other camera "
        "for the chunk to vote.")
    min_spread: float = Field(
        0.3, ge=0, description="Chunks whose points spread less (m, RMS) do not vote: a person "
        "standing still says nothing about time.")
    sigma: float = Field(
        0.2, gt=0, description="Residual scale (m) of the vote and verification kernels "
        "exp(-r^2 / 2 sigma^2): above detection noise, below lap-to-lap path differences.")
    max_offset_fraction: float = Field(
        1.0, gt=0, le=1, description="Largest |offset| searched as a fraction of the longer "
        "sequence (paper: one third; we search every offset with enough overlap).")
    n_candidates: int = Field(
        6, ge=1, description="Offset peaks verified by ICP per camera pair.")
    nms_seconds: float = Field(
        1.0, gt=0, description="Minimum separation (s) of two candidate peaks.")
    estimate_rate: bool = Field(
        True, description="Estimate the residual frame-rate ratio on top of the fps prior.")
    rate_prior_sd: float = Field(
        1e-3, gt=0, description="Prior s.d. of the frame-rate ratio around the fps/timestamp "
        "prior (1e-3: a 29.97 fps camera labelled 30 fps, ten times consumer clock drift); "
        "overlaps too short to measure the rate keep the prior.")
    offset_tolerance: float = Field(
        2.0, gt=0, description="Pairs whose offset disagrees with the globally consistent "
        "solution by more than this (frames) are rejected (cycle consistency).")
    evidence_seconds: float = Field(
        20.0, gt=0, description="Overlap (s) past which a candidate's ICP evidence no longer "
        "grows with the overlap's length (shorter overlaps count sqrt(overlap / this)). "
        "Measured 10 -> 20 s: simulator phones seed 2 (60 s), a camera looking almost level "
        "(poor ground tracks) whose 13 s coincidence 1418 frames off outscored the whole "
        "minute on the sum of its pairs, now exact; the other 32 scenes of 7 presets x seeds "
        "0-4 at 60 s that pass stage I exact either way; bench_sync.py table 1 (84 cameras) "
        "84/84 either way, its sub-frame columns unchanged; table 2b (the paper's single "
        "walker, 35 runs) 28/35 exact either way, the one wrong camera at offset 50 off by "
        "2.6 instead of 188 frames, cameras flagged ambiguous 23 -> 17.")
    camera_vote: bool = Field(
        True, description="After the pairwise sync, move each camera to the clock offset and "
        "heading that the ICP evidence summed over all of its pairs supports best (any "
        "pair's candidates are tried); periodic motion makes every pair of a camera show the "
        "same wrong peak, which outvotes the right pair in the pairwise consensus.")
    ambiguity_ratio: float = Field(
        0.8, gt=0, le=1, description="A pair whose second-best candidate scores above this "
        "fraction of the best is flagged ambiguous.")
    scan_seconds: float = Field(
        0.2, ge=0, description="An ambiguous pair (see ambiguity_ratio) also gets candidates "
        "from quick ICP at offsets this far apart (s) over the whole overlap: on a walker's "
        "circle the vote's peaks are the longest overlaps, not the truth. 0 = off.")
    scan_max_offsets: int = Field(
        120, ge=2, description="At most this many offsets are scanned per ambiguous pair (the "
        "step grows beyond scan_seconds on long recordings).")

    # -- rotation search and ICP (paper: "2D Rotation Search", "Iterative Closest Point") ------
    estimate_scale: bool = Field(
        True, description="Align ground planes by a 2D similarity instead of a rigid motion, "
        "correcting each camera's stage-I metric scale relative to the reference.")
    scale_range: float = Field(
        1.3, ge=1, description="Largest relative scale correction (and 1 / smallest).")
    icp_gate: float = Field(
        1.5, gt=0, description="Initial association gate (m) of the ICP; shrinks to 4 x RMS.")
    icp_min_gate: float = Field(0.3, gt=0, description="Smallest association gate (m).")
    icp_trim: float = Field(
        0.9, gt=0, le=1, description="Fraction of gated matches kept in each ICP fit.")
    icp_max_frames: int = Field(
        1500, ge=50, description="Frames subsampled for the ICP (speed).")
    rotation_step_deg: float = Field(
        5.0, gt=0, description="Angle step of the brute-force rotation search fallback (paper: "
        "all angles 0-360).")
    smooth_seconds: float = Field(
        0.1, ge=0, description="Gaussian smoothing (s) of the trajectories before the sub-frame "
        "fit; removes the half-frame bias of interpolating noisy samples.")
    n_workers: int = Field(
        2, ge=1, description="Workers making the cameras' ground trajectories and aligning the "
        "camera pairs in parallel (processes or threads, see processes), and threads of the "
        "camera vote and the epipolar clock step.")
    processes: bool = Field(
        True, description="Run the ground trajectories and the camera pairs in forked worker "
        "processes where this process can fork (Linux, not a daemonic process), else in "
        "threads. Their Python loops hold the GIL: on 4 "
        "cameras x 3000 frames x 5 persons and 2 cores the ground trajectories took 2.3 s in "
        "two threads (2.0-2.3 s in one), 1.1-1.2 s in two processes; the camera pairs 4.1 s in "
        "threads, 3.2-3.4 s in processes. Stages II-IV (bench_sync.py --only time, 5 runs, "
        "alternating with the threads): median wall 6.10 and 6.93 s in threads, 5.03, 3.80 "
        "and 3.95 s in processes (CPU 8.5-8.9 s -> 6.9-7.0 s). The results are the same.")
    refine_sigma: float = Field(
        0.03, gt=0, description="Noise floor (m) of ground points in the sub-frame offset / "
        "rate fit (ankle jitter of the gait); added to the per-camera range-dependent noise.")
    pixel_noise: float = Field(
        2.0, gt=0, description="Foot detection noise (px) of the ground noise model "
        "d^2 / (f h) per pixel, which weights the sub-frame fit.")

    # -- sub-frame clocks from the epipolar geometry (stages/epipolar_sync.py) ----------------
    epipolar_sync: bool = Field(
        True, description="After stage IV, correct every camera's time offset by the shift at "
        "which a fundamental matrix, fitted afresh at each shift, best explains the joints that "
        "two cameras see of the same persons (robust L1 over all pairs; "
        "stages/epipolar_sync.py). The ground trajectories leave offsets about half a frame "
        "off in a crowd; the epipolar geometry does not depend on stage IV's rotations or "
        "stage I's focal lengths. Measured with bench_sync.py's 24 scenes (84 cameras): "
        "integer part right 76 -> 84, median error 0.10-0.36 -> 0.03-0.08 frame per preset, "
        "worst 1.02 -> 0.27; on 24 whole-cascade scenes (real stage I, quick-matrix presets, "
        "seeds 0-5): 67 -> 84 of 84, median 0.24 -> 0.04 frame. About 0.5-1 s on 4 cameras x "
        "3000 frames x 5 persons.")
    epipolar_window_frames: float = Field(
        1.5, gt=0, description="Offset correction searched (reference frames) in the first "
        "iteration; a camera pair whose best shift lies on the window's edge is searched again "
        "over twice the window (stage IV once left a periodic walk 2.5 frames off); each later "
        "iteration searches half as far.")
    epipolar_candidates: int = Field(
        3, ge=1, description="An ambiguous pair (see ambiguity_ratio) is decided among its "
        "best this many candidates (those with at least half the best ICP evidence) by the "
        "epipolar geometry of the people's joints at each candidate's clock and ground "
        "alignment; 1 turns the check off. One lap off, a walker's ground path coincides to "
        "decimetres, its joints fit no two-view geometry.")
    epipolar_decisive: float = Field(
        0.9, gt=0, le=1, description="The epipolar check decides a pair only if its best "
        "candidate's cost is at most this fraction of the runner-up's; else the ICP evidence "
        "stands. The pair stays flagged ambiguous either way (the true candidate may not be "
        "among those checked). On "
        "bench_sync's table 2b the true candidate's cost was 0.75-0.83 of the next (0.54-0.78 "
        "when the cost was a Huber loss), and one pair at 0.94 was left to the ICP evidence, "
        "which was right; under the Huber loss one wrong choice came at 0.95.")
    epipolar_choice_seconds: float = Field(
        0.12, ge=0, description="The epipolar check takes each candidate's lowest cost over "
        "clocks up to this far (s) from its own: on a walker's circle the ground fit leaves "
        "true candidates a few frames off (a time shift looks like a turn).")
    epipolar_iterations: int = Field(
        2, ge=1, description="Most searches: search, correct and associate again (the "
        "association at the current clocks holds each search a little towards them: a first "
        "search left a third of a 0.5-0.7 frame error on simulated crowds), unless no camera "
        "moved by 0.15 frame or more.")
    epipolar_times: int = Field(
        300, ge=20, description="Reference times (evenly spread) whose persons are matched "
        "across cameras for the epipolar search.")
    epipolar_points: int = Field(
        8000, ge=100, description="Joint correspondences per camera pair (a random subset of "
        "the matched persons beyond).")

    # -- the rig from the epipolar geometry (stages/epipolar_rig.py) ---------------------------
    epipolar_rig: bool = Field(
        True, description="Last, refine every camera's focal length, principal point, rotation "
        "and centre so that the joints two cameras see of the same persons fit their epipolar "
        "geometry (no 3D points; priors hold the ground, heading and size of the rig where "
        "stage IV put them; stages/epipolar_rig.py). On 24 whole-cascade scenes (terrace, lab "
        "ring, crowd, periodic; seeds 0-5; 40 s) it took the worst relative rotation per scene "
        "from 1.07-4.86 to 0.38-2.38 deg, the worst camera centre after a similarity alignment "
        "from 0.10-0.49 m to 0.005-0.13 m and the worst focal length from 1.7-14.9 % to "
        "0.2-2.6 % off.")
    rig_rounds: int = Field(
        2, ge=1, description="Associations and solves of the rig refinement: the persons are "
        "matched again at the refined rig (in a crowd stage IV's rig mismatches some).")
    rig_points: int = Field(
        3000, ge=100, description="Joint correspondences per camera pair in the rig refinement "
        "(a random subset of the matched persons beyond).")
    rig_tilt_sigma_deg: float = Field(
        1.0, gt=0, description="Prior sd (deg) of each camera's tilt around stage I's in the rig "
        "refinement (stage I's tilts were 0.3-2.7 deg off on the 24 scenes).")
    rig_focal_sigma: float = Field(
        0.1, gt=0, description="Prior sd of each log focal length around stage I's in the rig "
        "refinement.")
    rig_principal_point_sigma: float = Field(
        0.02, gt=0, description="Prior sd of the principal point around the image centre in the "
        "rig refinement, as a fraction of the image width (Stage V's principal_point_sigma). "
        "Without the principal points free, the refinement left relative rotations 1-2.5 deg "
        "off on a periodic scene (0.1-0.6 deg with them).")
    rig_radial_sigma: float = Field(
        0.2, gt=0, description="Prior sd of the radial term per camera in the rig refinement, a "
        "first-order lens undistortion x + k (x - c) r^2 (r in focal lengths) that keeps lens "
        "distortion from bending the geometry; not reported (Stage V's lens pass estimates the "
        "distortion). Without it, on the simulated security cameras (60-100 deg field of view, "
        "barrel distortion 0.15) the refinement turned the cameras further off than stage IV "
        "had them (worst rotation vs the reference 2.3 -> 3.6 and 3.0 -> 6.2 deg at seeds 0 "
        "and 1); with it 1.0 and 1.0 deg.")
