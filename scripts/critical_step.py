"""The explicit integrator's critical step against the mesh size h, for the paper's per-spring
constants and for springs derived from a material (issue 13's last report item).

The whole mesh's linearised critical step (Model.critical_dt: the stiffest mode of
M^-1/2 K M^-1/2, anchors included, damping left out so that only stiffness and mass count) on
icospheres of radius 50 mm (subdivisions 2-6: a membrane) and tet balls of radius 50 mm (edges
16 to 6.5 mm). With fixed constants k and a mass that shrinks like h^2 (surface) or h^3 (volume)
the step falls like sqrt(m / k): h to h^1.5. With springs from E (k ~ E h on a volume, E t on a
membrane) and masses from rho, it is a wave crossing an edge: dt ~ h sqrt(rho / E).

    python scripts/critical_step.py          (about 1 min on 2 cores)
"""

import math

import numpy as np

from almsdm_warp.mesh.primitives import icosphere, tet_ball
from almsdm_warp.sim.model import Model
from almsdm_warp.tissue.material import Material
from almsdm_warp.tissue.params import TissueParams

E, NU, RHO = 10e3, 0.45, 1000.0
SURFACE = Material(E, NU, RHO, thickness=2e-3, foundation=1e6)  # 10 kPa, 2 mm wall, 1 kPa/mm foundation
VOLUME = Material(E, NU, RHO)
PAPER = TissueParams()  # 62 / 124 N/m springs, a 25 mm shell's lumped masses (the paper preset)


def undamped(tissue):
    """The same tissue with its dampers off: the critical step of stiffness and mass alone."""
    from dataclasses import replace

    if isinstance(tissue, Material):
        return replace(tissue, damping_ratio=0.0, rayleigh_alpha=0.0, rayleigh_beta=0.0)
    return replace(tissue, edge_damping=0.0, anchor_damping=0.0)


def row(mesh, label, tissue, anchors=True):
    h = float(mesh.edge_rest_length.mean())
    dt = Model(mesh, undamped(tissue), "cpu").critical_dt(anchors=anchors)
    return label, mesh.vertex_count, h, dt


def slope(rows):
    """The exponent p of dt ~ h^p, least squares in log-log over the rows."""
    h = np.log([r[2] for r in rows])
    dt = np.log([r[3] for r in rows])
    return float(np.polyfit(h, dt, 1)[0])


def table(title, rows, wave=None):
    print(f"\n{title}\n")
    print("| mesh | vertices | mean edge h [mm] | critical step [ms] | h sqrt(rho/E) [ms] |")
    print("|---|---|---|---|---|")
    for label, n, h, dt in rows:
        w = f"{h * math.sqrt(RHO / E) * 1e3:.4g}" if wave else "-"
        print(f"| {label} | {n} | {h * 1e3:.3g} | {dt * 1e3:.4g} | {w} |")
    print(f"\nfit: dt ~ h^{slope(rows):.2f}")


def main():
    spheres = [icosphere(50.0, s) for s in range(2, 7)]
    balls = [tet_ball(50.0, e) for e in (16.0, 12.0, 10.0, 8.0, 6.5)]
    table("(a) icosphere R 50 mm, the paper's constants", [row(m, f"subdivision {s}", PAPER) for s, m in zip(range(2, 7), spheres)])
    table("(b) icosphere R 50 mm, material (E 10 kPa, 2 mm wall, foundation 1 kPa/mm)",
          [row(m, f"subdivision {s}", SURFACE) for s, m in zip(range(2, 7), spheres)], wave=True)
    table("(c) tet ball R 50 mm, the paper's constants", [row(m, f"edge {e:g} mm", PAPER) for e, m in zip((16, 12, 10, 8, 6.5), balls)])
    table("(d) tet ball R 50 mm, material (E 10 kPa, nu 0.45), no anchors",
          [row(m, f"edge {e:g} mm", VOLUME, anchors=False) for e, m in zip((16, 12, 10, 8, 6.5), balls)], wave=True)


if __name__ == "__main__":
    main()
