"""The stages run with one BLAS thread, and give the caller's setting back afterwards."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from cascalib.blas import one_blas_thread
from cascalib.stages import align, reconstruct, refine, single_view


def _blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_one_thread_inside_and_the_callers_setting_after() -> None:
    assert _blas_threads(), "numpy's BLAS is not visible to threadpoolctl"
    with threadpool_limits(limits=2, user_api="blas"):
        inside = one_blas_thread(_blas_threads)()
        assert inside == [1] * len(inside)
        assert _blas_threads() == [2] * len(inside)


class _Seen(Exception):
    """Raised by a stage's first inner step with the BLAS threads it saw."""


_TRACKS = type("T", (), {"require_image_size": lambda self: (640, 480)})()


@pytest.mark.parametrize(("module", "stage", "inner", "args"), [
    (single_view, "calibrate_single_view", "_upright", (_TRACKS,)),
    (align, "align_cameras", "_check_inputs", ([], [])),
    (refine, "refine", "prepare", ([], None)),
    (reconstruct, "triangulate_poses", "match_calibration", ([], None)),
])
def test_each_stage_computes_with_one_blas_thread(monkeypatch: pytest.MonkeyPatch, module: object,
                                                  stage: str, inner: str,
                                                  args: tuple[object, ...]) -> None:
    def spy(*args: object, **kwargs: object) -> None:
        raise _Seen(_blas_threads())

    monkeypatch.setattr(module, inner, spy)
    with threadpool_limits(limits=2, user_api="blas"), pytest.raises(_Seen) as seen:
        getattr(module, stage)(*args)
    threads = seen.value.args[0]
    assert threads and all(n == 1 for n in threads)
    assert np.all(np.array(_blas_threads()) == 2)  # restored after the stage raised
