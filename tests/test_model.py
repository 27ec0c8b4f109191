"""Model construction, parameters by name, switching terms, and bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vfjax
from vfjax import (
    BernoulliForce,
    ClosureHold,
    Elastic,
    FlowSeparation,
    Subject,
    TanhDamping,
)


def test_paper_units_are_converted_to_cgs():
    m = vfjax.preset("N1")
    p = m.params()
    assert float(p["K"]) == pytest.approx(396.6550 * 1000.0)  # N/m -> dyne/cm
    assert float(p["S"]) == pytest.approx(43.7988)  # px/mm², kept as the paper's S
    assert float(p["t_c"]) == pytest.approx(5.25e-3)
    assert float(p["P_s"]) == pytest.approx(11250.0)
    assert float(p["M"]) == pytest.approx(0.12) and float(p["l"]) == pytest.approx(1.6)
    female = vfjax.preset("N3").params()
    assert float(female["M"]) == pytest.approx(0.075) and float(female["l"]) == pytest.approx(1.0)
    assert m.parameter_units()["K"] == "dyne/cm"


def test_contact_and_subcritical_displacement():
    m = vfjax.preset("N1")
    # eq. 5: x_0 = -A_g0 / (2 l)
    assert float(m.contact_displacement) == pytest.approx(-0.05 / 3.2)
    # x_c is where the Bernoulli force vanishes (F_s.a. = 0): check with the force itself.
    xc = m.subcritical_displacement()
    s = m.subject
    f = BernoulliForce().open_force(
        s.area(xc), s.subglottal_pressure, s.air_density, s.air_viscosity, s.thickness, s.length
    )
    assert abs(float(f)) < 1e-9
    assert float(m.contact_displacement) < float(xc) < 0.0


def test_flow_velocity_solves_equation_7():
    """The cancellation-free root must satisfy the paper's quadratic (eq. 7) itself."""
    rng = np.random.default_rng(0)
    b = BernoulliForce()
    rho, mu, d, l = 1.3e-3, 1.8e-4, 0.32, 1.6
    for area, pressure in zip(rng.uniform(1e-4, 0.2, 50), rng.uniform(500, 20000, 50)):
        q = float(b.particle_velocity(area, pressure, rho, mu, d, l)) * area
        residual = 0.875 * rho * q**2 / (2 * area**2) + 12 * mu * d * l**2 * q / area**3 - pressure
        assert abs(residual) < 1e-9 * pressure
        # and it is the positive root of the textbook formula
        a_, b_ = 0.875 * rho / (2 * area**2), 12 * mu * d * l**2 / area**3
        textbook = (-b_ + np.sqrt(b_**2 + 4 * a_ * pressure)) / (2 * a_)
        assert q == pytest.approx(textbook, rel=1e-6)


def test_flow_force_limits():
    """F_a -> P_s l d / 2 as the glottis closes, and < 0 when it is wide open."""
    b = BernoulliForce()
    P, rho, mu, d, l = 11250.0, 1.3e-3, 1.8e-4, 0.32, 1.6
    closed_limit = float(b.open_force(1e-6, P, rho, mu, d, l))
    assert closed_limit == pytest.approx(P * l * d / 2, rel=1e-9)
    assert float(b.open_force(0.1, P, rho, mu, d, l)) < 0


def test_set_and_params_round_trip_and_trace():
    m = vfjax.preset("N2")
    m2 = m.set(K=2.0e5, C_f=100.0, S=10.0, t_c=1e-3, P_s=9000.0)
    p = m2.params()
    assert float(p["K"]) == 2.0e5 and float(p["C_f"]) == 100.0 and float(p["S"]) == 10.0
    assert float(p["t_c"]) == 1e-3 and float(p["P_s"]) == 9000.0
    assert float(m.params()["K"]) == pytest.approx(113971.0)  # the original is untouched
    # set() is traceable: a gradient flows through it
    g = jax.grad(lambda k: m.set(K=k).params()["K"] * 2.0)(1.0)
    assert float(g) == 2.0
    with pytest.raises(KeyError, match="no parameter 'eta'"):
        m.set(eta=1.0)


def test_switching_terms_off_and_on():
    m = vfjax.preset("N1")
    no_fs = m.without(FlowSeparation)
    assert not no_fs.has(FlowSeparation) and no_fs.has(ClosureHold)
    assert no_fs.with_term(FlowSeparation()).has(FlowSeparation)
    no_hold = m.without(ClosureHold)
    assert no_hold.closure_duration is None
    with pytest.raises(ValueError, match="no term FlowSeparation"):
        no_fs.without(FlowSeparation)
    replaced = m.with_term(Elastic(K=1.0e5))
    assert float(replaced.params()["K"]) == 1.0e5
    assert len(replaced.terms) == len(m.terms)


@pytest.mark.parametrize(
    "build, name",
    [
        (lambda: Subject(mass=0.0), "mass"),
        (lambda: Subject(length=-1.0), "length"),
        (lambda: Subject(thickness=0.0), "thickness"),
        (lambda: Subject(mass=float("nan")), "mass"),
        (lambda: Subject(subglottal_pressure=-5.0), "subglottal_pressure"),
        (lambda: Elastic(K=0.0), "K"),
        (lambda: Elastic(K=float("nan")), "K"),
        (lambda: TanhDamping(C_f=-1.0), "C_f"),
        (lambda: ClosureHold(t_c=-1e-3), "t_c"),
        (
            lambda: vfjax.paper_model(
                K_N_per_m=-3.0,
                C_f_g_per_s=1.0,
                S_px_per_mm2=1.0,
                t_c_s=1e-3,
                P_s_dyne_per_cm2=1e4,
                sex="male",
            ),
            "K",
        ),
        (
            lambda: (
                vfjax.preset("N1")
                .set(S=0.0)
                .__class__(vfjax.preset("N1").subject, vfjax.preset("N1").terms, 0.0)
            ),
            "S",
        ),
    ],
)
def test_non_physical_parameters_raise_naming_the_parameter(build, name):
    with pytest.raises(ValueError, match=name):
        build()


def test_bad_simulation_settings_raise():
    m = vfjax.preset("N1")
    with pytest.raises(ValueError, match="fps"):
        vfjax.simulate(m, 0.0, 10)
    with pytest.raises(ValueError, match="fps"):
        vfjax.simulate(m, float("nan"), 10)
    with pytest.raises(TypeError, match="fps"):
        vfjax.simulate(m, jnp.asarray(4000.0), 10)
    with pytest.raises(ValueError, match="n_frames"):
        vfjax.simulate(m, 4000.0, 0)
    with pytest.raises(ValueError, match="preset"):
        vfjax.preset("N9")


def test_duplicate_terms_rejected():
    m = vfjax.preset("N1")
    with pytest.raises(ValueError, match="at most one term"):
        vfjax.VocalFoldModel(m.subject, m.terms + (FlowSeparation(),), m.S)
