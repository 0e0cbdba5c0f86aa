"""The explicit step's rigid sphere on a tet body: its hold force against the implicit step's.

The implicit step's sphere is checked against a static solve (tests/test_implicit_sphere.py); here
the explicit projection must give the same hold force where the sphere, pressed beside a support,
reaches over held vertices and a light surface vertex is squeezed against it: the case where
putting a deep step's end straight onto the sphere along its normal scaled the vertex's sliding
each step and the force wandered 15% above the implicit one through the hold.
"""

import numpy as np
import pytest

from almsdm_warp.mesh import primitives
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.scene.loader import resolve_scene_or_mesh

SUPPORT = -0.01
"""Every vertex below this height [m] is held: the ball's lower part sits in its bed."""


@pytest.fixture(scope="module")
def supported_ball():
    """A tet ball (R 20 mm, edges 6 mm, 252 vertices) on the shipped liver's material, and its contact:
    of the surface vertices less than 1 mm above the support, the one farthest along +y (the sphere
    pressing there along the inward normal reaches the held vertices below it)."""
    mesh = primitives.tet_ball(20.0, 6.0)
    v = mesh.vertices
    low = [int(i) for i in mesh.surface_vertices if SUPPORT < v[i, 2] < SUPPORT + 0.001]
    contact = max(low, key=lambda i: v[i, 1])
    return mesh, resolve_scene_or_mesh("liver").tissue, contact


def hold_forces(mesh, tissue, contact, integrator, dt, device):
    pal = Palpation(mesh, tissue, rings="global", integrator=integrator, dt=dt, device=device,
                    probe_radius=0.01, fixed_below=SUPPORT)
    pal.touch(contact, 0.01)
    result = pal.press(0.01, ramp=0.1, hold=0.2, settle=dt)
    ramp_end = result.release_step - round(0.2 / dt)
    return result.force[(ramp_end + result.release_step) // 2 : result.release_step]  # the hold's second half


def test_explicit_hold_force_is_the_implicit_one_on_tets(device, supported_ball):
    mesh, tissue, contact = supported_ball
    implicit = hold_forces(mesh, tissue, contact, "implicit", 1e-3, device)
    reference = implicit[-1]
    assert reference > 0.1  # several vertices touch: the force of a real press
    np.testing.assert_allclose(implicit, reference, rtol=0.01)  # the implicit hold is steady
    for dt in (1e-3, 2.5e-4):
        explicit = hold_forces(mesh, tissue, contact, "explicit", dt, device)
        # steady through the hold and within 2% of the implicit force at every step of it
        np.testing.assert_allclose(explicit, reference, rtol=0.02, err_msg=f"explicit at dt {dt * 1e3:g} ms")
