"""The virtual coupling (protocol/coupling.py) against closed forms: springs in series at rest, the
energy a sampled loop puts out over a closed device path, and the passivity condition
b > K T / 2 + |B| (Colgate & Schenkel 1997). Plain NumPy: no device."""

import math

import numpy as np
import pytest

from almsdm_warp.protocol.coupling import VirtualCoupling, passive_stiffness, passivity_margin

T = 1e-3  # 1 kHz


def settle(coupling, device, env, steps):
    """Hold the device at `device` [m] for `steps` periods; env(x_t) is the force on the tool."""
    f = np.zeros(3)
    for _ in range(steps):
        f = coupling.update(device, env(coupling.tool))
    return f


@pytest.mark.parametrize("k_c, k_e", [(500.0, 240.0), (2000.0, 80.0), (300.0, 3000.0)])
def test_a_device_pushed_into_a_linear_spring_feels_the_springs_in_series(k_c, k_e):
    c = VirtualCoupling(k_c, 0.05, T, device_damping=k_c * T / 2 + 0.05 + 0.1)
    c.reset(np.zeros(3))
    push = np.array([0.0, 0.0, -0.008])  # 8 mm into a spring at rest at the origin
    f = settle(c, push, lambda x: -k_e * x, 6000)
    series = k_c * k_e / (k_c + k_e)
    np.testing.assert_allclose(f, -series * push, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(c.tool, k_c / (k_c + k_e) * push, rtol=1e-6, atol=1e-12)


def loop_energy(c, env, device_damping, amplitude=0.004, hz=5.0, cycles=4):
    """The energy [J] the sampled loop puts into the device over its last closed cycle: the held
    force F_k over each sample's motion (the zero-order hold: sum F_k . (x_{k+1} - x_k)) less what
    the device's damper takes, b int v^2 dt = b A^2 w^2 P / 2 over a cycle of x_d = A sin(w t)."""
    w = 2 * math.pi * hz
    n = int(round(1.0 / (hz * T)))  # samples a cycle
    k = np.arange(cycles * n + 1)
    x = np.zeros((len(k), 3))
    x[:, 2] = amplitude * np.sin(w * k * T)
    c.reset(x[0])
    work = 0.0
    for i in range(len(k) - 1):
        f = c.update(x[i], env(c.tool))
        if i >= (cycles - 1) * n:
            work += float(f @ (x[i + 1] - x[i]))
    return work - device_damping * amplitude**2 * w**2 * (n * T) / 2


@pytest.mark.parametrize("k_e", [0.0, 240.0, 5000.0])
@pytest.mark.parametrize("hz", [2.0, 10.0, 40.0])
def test_a_passive_coupling_puts_out_no_energy_over_a_closed_device_path(k_e, hz):
    b = 0.6  # N s/m: a device's physical damping
    k_c = passive_stiffness(b, T, damping=0.1)
    c = VirtualCoupling(k_c, 0.1, T, device_damping=b)
    assert loop_energy(c, lambda x: -k_e * x, b, hz=hz) <= 0.0


def test_the_passivity_bound_is_where_a_held_spring_starts_to_put_out_energy():
    # a tool held still (a very heavy one): the device feels the sampled spring k_c alone, which
    # gives out about k_c T / 2 int v^2 dt a cycle; a device damping at 0.8 of that bound loses
    k_c = 1000.0
    bound = k_c * T / 2
    held = VirtualCoupling(k_c, 0.0, T, device_damping=1.01 * bound, tool_mass=1e9)
    assert loop_energy(held, lambda x: np.zeros(3), 1.01 * bound) <= 0.0
    held = VirtualCoupling(k_c, 0.0, T, device_damping=1.01 * bound, tool_mass=1e9)
    assert loop_energy(held, lambda x: np.zeros(3), 0.8 * bound) > 0.0


def test_a_coupling_that_violates_the_passivity_condition_is_refused():
    with pytest.raises(ValueError, match=r"not passive at T 1 ms.*b > k_c T / 2 \+ \|b_c\| = 0\.6 N s/m.*at most 800 N/m"):
        VirtualCoupling(1000.0, 0.1, T, device_damping=0.5)
    assert passivity_margin(1000.0, 0.1, 0.5, T) == pytest.approx(-0.1)
    k = passive_stiffness(0.5, T, damping=0.1, safety=0.9)
    assert k == pytest.approx(0.9 * 800.0)
    VirtualCoupling(k, 0.1, T, device_damping=0.5)  # accepted
    with pytest.raises(ValueError, match="coupling stiffness"):
        VirtualCoupling(-1.0, 0.0, T, device_damping=1.0)
    with pytest.raises(ValueError, match="leaves nothing for a spring"):
        passive_stiffness(0.1, T, damping=0.2)
