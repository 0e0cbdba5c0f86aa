"""The press schedule: step counts of ramp, hold and settle at a step dt, and the ramp's fraction."""

import pytest

from almsdm_warp.protocol.schedule import PressSchedule, check_press


@pytest.mark.parametrize("dt", [1e-3, 5e-3, 0.7e-3, 0.25])
@pytest.mark.parametrize("times", [(0.1, 0.2, 1.0), (0.0, 0.0, 0.0), (0.0104, 0.0005, 0.3)])
def test_steps_are_the_rounded_times(dt, times):
    ramp, hold, settle = times
    s = PressSchedule.from_times(dt, ramp, hold, settle)
    assert s.ramp_n == max(int(round(ramp / dt)), 1) and s.hold_n == int(round(hold / dt))
    assert s.settle_n == max(int(round(settle / dt)), 1)
    assert s.release_step == s.ramp_n + s.hold_n and s.total == s.release_step + s.settle_n
    assert [s.fraction(k) for k in range(s.release_step)] == [min((k + 1) / s.ramp_n, 1.0) for k in range(s.release_step)]
    assert s.fraction(s.ramp_n - 1) == 1.0


def test_a_press_of_100_ms_ramp_at_1_ms():
    s = PressSchedule.from_times(1e-3, 0.1, 0.2, 1.0)
    assert (s.ramp_n, s.hold_n, s.settle_n, s.release_step, s.total) == (100, 200, 1000, 300, 1300)
    assert s.fraction(0) == 0.01 and s.fraction(49) == 0.5 and s.fraction(250) == 1.0


def test_bad_press_values_name_the_first():
    check_press(depth=0.01, ramp=0.0)
    with pytest.raises(ValueError, match=r"press depth must be > 0, got 0.0"):  # a press of depth 0 has no stiffness
        check_press(depth=0.0, ramp=0.1)
    with pytest.raises(ValueError, match=r"press hold must be >= 0, got -1"):
        check_press(depth=0.01, ramp=0.1, hold=-1, settle=float("nan"))
    with pytest.raises(ValueError, match=r"press force must be finite, got nan"):
        check_press(force=float("nan"), ramp=-1)
    with pytest.raises(ValueError, match=r"press ramp must be 0 or of magnitude 1e-12 to 1e\+12, got 1e\+300"):
        check_press(depth=0.01, ramp=1e300)
