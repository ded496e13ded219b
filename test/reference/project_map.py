"""The one place where the project's coach parameters meet the reference's (explicit map).

The reference (coach_ode) and the project (railgsa_ros.models.coach) describe the same 10-DOF
coach with the same coordinates, order and signs, but count two elements differently:

=========================  ============================  ===================================
quantity                   project (coach file)          reference (coach_ode Params)
=========================  ============================  ===================================
masses, inertias           m_c, J_c, m_b, J_b, m_w       M_c, J_c, M_b, J_b, M_w (equal)
primary spring, damper     k_p, c_p per axle box         k_p, c_p per axle box (equal)
secondary spring, damper   k_s, c_s per bogie side       k_s, c_s per bogie side (equal)
wheel-rail contact         k_h per WHEEL                 k_H per WHEELSET = 2 k_h
bogie spacing              bogie_spacing_m (L)           l_c semi-spacing = L / 2
wheelbase                  wheelbase_m (a)               l_t semi-wheelbase = a / 2
IMU position, reference    x_m forward of the centre     x_p forward of the centre (equal);
                           wheelset 1..4                 reference index 0..3
=========================  ============================  ===================================

It takes the project's values as plain numbers (a mapping by the project's names) and imports
nothing of railgsa_ros, so the reference's code path stays independent of the project's.
"""

from __future__ import annotations

from collections.abc import Mapping

from .coach_ode import Params

EQUAL = {'m_c': 'M_c', 'J_c': 'J_c', 'm_b': 'M_b', 'J_b': 'J_b', 'm_w': 'M_w', 'k_p': 'k_p',
         'c_p': 'c_p', 'k_s': 'k_s', 'c_s': 'c_s'}


def reference_params(values: Mapping[str, float], bogie_spacing_m: float,
                     wheelbase_m: float) -> Params:
    """Reference Params of a coach given by the project's parameter values (SI, the names of
    a coach file's ``vehicle:`` section) and geometry (m)."""
    out = {ref: float(values[name]) for name, ref in EQUAL.items()}
    return {**out, 'k_H': 2.0 * float(values['k_h']), 'l_c': bogie_spacing_m / 2,
            'l_t': wheelbase_m / 2}
