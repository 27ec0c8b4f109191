"""Could a GAW tell a Hertz contact force? MODEL_SPEC.md lists Hertz contact among the
candidate effects: while the folds are pressed together past contact (x < x_0), a force
k_H (x_0 - x)^(3/2) (dyne; k_H in dyne/cm^1.5) pushes them apart. This script adds such a
force to the paper's four subjects, with the closure hold and without it (t_c = 0), and
prints how far the folds press past contact and how much the force changes the GAW (NMSE
against the same model without it) for k_H from 1e4 (about the Hertz stiffness of soft
tissue, E ~ 10 kPa, on a contact radius of a few mm) to 1e9 dyne/cm^1.5.

Run: python benchmarks/hertz_contact.py
"""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import vfjax

FPS, FRAMES = 4000.0, 201
STIFFNESSES = (1e4, 1e6, 1e8, 1e9)  # k_H, dyne/cm^1.5


class HertzContact(vfjax.AbstractForce):
    """k_H (x_0 - x)^(3/2) (dyne) while the glottis is closed, 0 while air flows."""

    k_H: jnp.ndarray = eqx.field(default=0.0, converter=vfjax.as_parameter)
    parameters: ClassVar = {"k_H": ("k_H", "dyne/cm^1.5")}

    def force(self, ctx):
        depth = ctx.x0 - ctx.x
        pressed = ~ctx.flow & (depth > 0)
        safe = jnp.where(pressed, depth, 1.0)  # no NaN gradient at depth <= 0
        return jnp.where(pressed, self.k_H * safe * jnp.sqrt(safe), 0.0)


def _gaw(model):
    sim = vfjax.simulate(model, FPS, FRAMES)
    return np.maximum(np.asarray(sim.area), 0.0), np.asarray(sim.displacement)


def main():
    print(
        "| subject | hold | pressed past x_0 (um) | closed frames | "
        + " | ".join(f"NMSE change, k_H {k:.0e}" for k in STIFFNESSES)
        + " |"
    )
    print("|---" * (4 + len(STIFFNESSES)) + "|")
    for name in ("N1", "N2", "N3", "N4"):
        for hold in (True, False):
            model = vfjax.preset(name)
            model = model if hold else model.set(t_c=0.0)
            area, x = _gaw(model)
            depth = float(model.contact_displacement - x.min()) * 1e4
            changes = []
            for k in STIFFNESSES:
                pressed, _ = _gaw(model.with_term(HertzContact(k_H=k)))
                changes.append(float(np.sum((pressed - area) ** 2) / np.sum(area**2)))
            print(
                f"| {name} | {'t_c' if hold else 'none'} | {depth:.2f} | "
                f"{int(np.sum(area <= 0))} / {FRAMES} | "
                + " | ".join(f"{c:.1e}" for c in changes)
                + " |",
                flush=True,
            )


if __name__ == "__main__":
    main()
