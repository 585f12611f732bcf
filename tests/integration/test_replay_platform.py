"""``swarm replay --check`` across floating-point platforms: exact where the run was recorded, a stated tolerance elsewhere."""

from __future__ import annotations

import numpy as np

from coordinator.replay_check import CROSS_PLATFORM_RTOL, RecordedRun, compare_estimate, same_float_platform
from runtime.models.state import SwarmEstimate
from runtime.recording.mcap_log import float_platform, software_versions
from runtime.wire.messages import EstimateMessage


def _estimate(x: float) -> SwarmEstimate:
    poses = np.array([[x, -0.25, np.pi - 1e-12], [0.0, 0.0, 0.0]])
    cov = np.stack([np.diag([1e-4, 2e-4, 3e-3]), np.array([[1e-4, 5e-5, 0.0], [5e-5, 1e-4, 0.0], [0.0, 0.0, 1e-3]])])
    return SwarmEstimate(np.array([3, 7]), poses, cov)


def _recorded(x: float) -> EstimateMessage:
    return EstimateMessage.from_estimate(_estimate(x), run="r1", step=4, stamp_ns=0)


def test_the_platform_is_in_every_recording_s_versions() -> None:
    versions = software_versions()
    assert versions["float_platform"] == float_platform()
    assert versions["numpy"] in float_platform()


def test_a_last_bit_difference_fails_on_the_same_platform_and_passes_across() -> None:
    x = 0.29404393308921695
    later = np.nextafter(x, 1.0)
    d = compare_estimate(4, _recorded(x), _estimate(later))
    assert d is not None and d.robot == 3 and d.field == "pose.x"
    assert compare_estimate(4, _recorded(x), _estimate(later), exact=False) is None


def test_a_real_difference_fails_across_platforms_too() -> None:
    x = 0.5
    d = compare_estimate(4, _recorded(x), _estimate(x * (1 + 10 * CROSS_PLATFORM_RTOL)), exact=False)
    assert d is not None and d.field == "pose.x"


def test_only_the_same_platform_string_is_exact(tmp_path) -> None:
    def rec(meta: dict) -> RecordedRun:
        return RecordedRun(tmp_path / "x.mcap", {}, meta)

    assert same_float_platform(rec({"versions": {"float_platform": float_platform()}}))
    assert not same_float_platform(rec({"versions": {"float_platform": "numpy 1.26.4, scipy 1.11.0, aarch64 baseline"}}))
    assert not same_float_platform(rec({}))  # an older recording that does not name its platform
