"""The project's coach (railgsa_ros.models.coach, simulate.simulate_model) against the
independent reference coach (test/reference/coach_ode: assembled matrices, a direct solve per
frequency, a Newton-Euler ODE integrated by solve_ivp) for the same parameter values, mapped
explicitly by reference.project_map (contact per wheel -> per wheelset, spacings -> semi-
spacings; everything else per axle box / per bogie side in both).

Tolerances. Frequency responses are exact in both codes (a modal sum, a linear solve): they
agree to 1e-6 relative. The time simulations are not both exact: the project discretises with
a first-order hold (exact for a profile linear between samples), the reference integrates the
smooth profile itself (DOP853, converged to < 1e-6 of the peak, test_reference_coach). Their
difference on a smooth profile is the hold's interpolation error, of order (omega dt)^2 / 12:
it must fall fourfold per halving of dt (nothing else in the difference does), be below 1e-6
of each channel's peak at 16 kHz, and vanish to the reference's own accuracy once
extrapolated to dt = 0 (Richardson; measured 1e-10 to 4e-10). For scale: the ADXL355's noise
at 1 kHz is 5.5e-3 m/s^2 per sample, 2-8 % of these runs' car-body peaks, so a model difference
that mattered to the inversion would show at 1e-3 or more, three orders above these tolerances.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from reference.coach_ode import (
    frequency_response,
    matrices,
    profile_response,
    simulate,
    wheelset_offsets,
)
from reference.project_map import reference_params

from railgsa_ros.models import load_model
from railgsa_ros.models.coach import PARAM_NAMES, CoachModel, ImuPosition
from railgsa_ros.simulate import simulate_model

COACH_FILE = Path(__file__).resolve().parents[1] / 'config' / 'vehicles' / 'coach.yaml'
SHIPPED = load_model(COACH_FILE)
assert isinstance(SHIPPED, CoachModel)
#: the primary IMU above the leading bogie, a further one at the car centre: channels
#: accel_z (front), pitch_rate, accel_z:centre
MODEL = CoachModel(SHIPPED.params, replace(SHIPPED.geometry, imus=(
    ImuPosition('front', SHIPPED.geometry.bogie_spacing_m / 2), ImuPosition('centre', 0.0))))
OUTPUTS = (MODEL.geometry.imus[0].x_m, None, 0.0)  # the same channels in the reference
#: a parameter set away from the nominal (each 10-30 % off, both signs): the map must hold for
#: any values, not only the file's
OFF = MODEL.theta * np.array([1.2, 0.8, 1.1, 0.7, 1.3, 0.9, 1.25, 1.15, 0.75, 0.8])


def reference_of(theta: np.ndarray) -> dict[str, float]:
    """The reference's parameters of the project's coach MODEL with parameters theta."""
    return reference_params(dict(zip(PARAM_NAMES, theta, strict=True)),
                            MODEL.geometry.bogie_spacing_m, MODEL.geometry.wheelbase_m)


@pytest.mark.parametrize('theta', [MODEL.theta, OFF], ids=['file', 'off'])
def test_the_map_gives_the_same_equations_of_motion(theta: np.ndarray) -> None:
    mass, c, k, k_u = MODEL.matrices(theta)
    m_ref, c_ref, k_ref, b_ref = matrices(reference_of(theta))
    np.testing.assert_array_equal(np.diag(m_ref), mass)
    np.testing.assert_allclose(c, c_ref, rtol=0, atol=1e-14 * np.abs(c_ref).max())
    np.testing.assert_allclose(k, k_ref, rtol=0, atol=1e-14 * np.abs(k_ref).max())
    np.testing.assert_allclose(k_u, b_ref, rtol=1e-15)
    np.testing.assert_array_equal(MODEL.wheel_offsets_m, wheelset_offsets(reference_of(theta)))


@pytest.mark.parametrize('theta', [MODEL.theta, OFF], ids=['file', 'off'])
def test_frequency_responses_agree_to_1e_6(theta: np.ndarray) -> None:
    """Per wheelset, every channel at every frequency from 0.01 to 300 Hz (none has a zero
    there); with the wheelsets' delays at 20 and 40 m/s relative to the channel's largest
    value (the delayed sums have nulls, where a relative error is meaningless)."""
    p = reference_of(theta)
    f = np.geomspace(0.01, 300.0, 3000)
    ours = MODEL.frequency_response(theta, 2j * np.pi * f)  # (C, W, F)
    ref = np.moveaxis(frequency_response(p, 2 * np.pi * f, OUTPUTS), 0, -1)  # (C, W, F)
    assert np.max(np.abs(ours - ref) / np.abs(ref)) < 1e-6
    for speed in (20.0, 40.0):
        ours = MODEL.track_response(theta, f, speed)
        ref = profile_response(p, 2 * np.pi * f, OUTPUTS, speed).T
        scale = np.abs(ref).max(axis=1, keepdims=True)
        assert np.max(np.abs(ours - ref) / scale) < 1e-6


def waves(x: np.ndarray) -> np.ndarray:
    """A smooth profile (m): waves of 31, 9 and 4 m (1, 0.5, 0.2 mm), faded in over 20-40 m of
    chainage (zero before: the coach starts at rest on flat track)."""
    fade = 0.5 - 0.5 * np.cos(np.pi * np.clip((x - 20.0) / 20.0, 0.0, 1.0))
    return fade * (1e-3 * np.sin(2 * np.pi * x / 31.0) + 5e-4 * np.sin(2 * np.pi * x / 9.0 + 1)
                   + 2e-4 * np.sin(2 * np.pi * x / 4.0 + 2))


def project_run(chainage: Callable[[np.ndarray], np.ndarray], seconds: float, rate_hz: float,
                every: int) -> np.ndarray:
    """The project's channels (3, T) at every ``every``-th sample of an FOH simulation at
    rate_hz, each wheelset on the profile at its own chainage (reference minus its offset)."""
    t = np.arange(round(seconds * rate_hz)) / rate_hz
    u = waves(chainage(t)[None, :] - MODEL.wheel_offsets_m[:, None])
    return simulate_model(u, 1.0 / rate_hz, MODEL)[:, ::every]


Speed = float | Callable[[float], float]
SPEEDS: dict[str, tuple[Speed, Callable[[np.ndarray], np.ndarray]]] = {
    # speed (m/s) of the reference wheelset and its chainage x(t) from 20 m
    'constant 25 m/s': (25.0, lambda t: 20.0 + 25.0 * t),
    '10 m/s + 20 m/s^2': (lambda t: 10.0 + 20.0 * t, lambda t: 20.0 + 10.0 * t + 10.0 * t ** 2),
}


@pytest.mark.slow  # about 4 s of CPU each (the ODE)
@pytest.mark.parametrize('case', SPEEDS)
def test_time_simulation_agrees_with_the_ode(case: str) -> None:
    """2 s from rest (the profile's waves reach the car body; the trailing wheelset, 21.56 m
    behind, sees them only at the end of the varying-speed run), output at 1 kHz."""
    speed, chainage = SPEEDS[case]
    t = np.arange(0.0, 2.0, 1e-3)
    run = simulate(reference_of(MODEL.theta), waves, speed, t, start_m=20.0)
    ref = np.array([run.accel(OUTPUTS[0]), run.pitch_rate(), run.accel(OUTPUTS[2])])
    scale = np.abs(ref).max(axis=1)
    assert scale[0] > 0.02 and scale[1] > 1e-4  # m/s^2, rad/s: the waves moved the car body
    errors = {}
    for rate in (8000.0, 16000.0):
        errors[rate] = project_run(chainage, 2.0, rate, round(rate / 1000)) - ref
    coarse, fine = (np.abs(e).max(axis=1) / scale for e in errors.values())
    assert np.all(fine < 1e-6), fine
    assert np.all((coarse / fine > 3.8) & (coarse / fine < 4.2)), coarse / fine  # (omega dt)^2
    extrapolated = (4 * errors[16000.0] - errors[8000.0]) / 3
    assert np.all(np.abs(extrapolated).max(axis=1) / scale < 2e-9)
