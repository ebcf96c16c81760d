"""The stage II-IV plots write readable PNGs with one panel per camera pair."""

from __future__ import annotations

import matplotlib.image as mpimg
import pytest
from align_scene import make_scene

from cascalib.stages.align import align_cameras


@pytest.fixture(scope="module")
def result():
    sc = make_scene(n_cams=3, n_persons=2, n_ref_frames=400, offsets=[0.0, 50.0, -30.0],
                    seed=5)
    return align_cameras(sc.tracks, sc.plane, rng=0)


def test_sync_curves_png(result, tmp_path) -> None:
    from cascalib.stages.align_plot import plot_sync_curves

    fig = plot_sync_curves(result, tmp_path / "sync.png")
    img = mpimg.imread(tmp_path / "sync.png")
    assert img.shape[0] > 200 and img.shape[1] > 400
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert len(titles) == 3 and titles[0].startswith("cam0 - cam1: offset 50.")


def test_ground_png(result, tmp_path) -> None:
    from cascalib.stages.align_plot import plot_ground_alignment

    fig = plot_ground_alignment(result, tmp_path / "ground.png")
    assert mpimg.imread(tmp_path / "ground.png").shape[0] > 400
    ax = fig.axes[0]
    labels = {t.get_text().split()[0] for t in ax.texts if t.get_text().strip()}
    assert labels == {"cam0", "cam1", "cam2"}


def test_epipolar_curves_png(result, tmp_path) -> None:
    from cascalib.simulate import simulate
    from cascalib.stages.align_plot import plot_epipolar_curves

    # the ankles-only rig above gives the epipolar search nothing to fit: no plot
    assert result.epipolar is not None and not result.epipolar.pairs
    assert plot_epipolar_curves(result) is None
    sc = simulate("terrace", seed=2, duration_s=15.0)
    people = align_cameras(sc.tracks, [sc.plane_camera(t.camera)[0] for t in sc.tracks], rng=0)
    fig = plot_epipolar_curves(people, tmp_path / "epipolar.png")
    assert mpimg.imread(tmp_path / "epipolar.png").shape[1] > 400
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles and all(" frame against cam" in t for t in titles)
    lines = [ln for ax in fig.axes for ln in ax.get_lines()]
    assert any(len(ln.get_xdata()) >= 7 for ln in lines)  # a sampled cost curve
