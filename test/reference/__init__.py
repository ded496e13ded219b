"""Independent reference for the coach: a 10-DOF vertical multibody ODE and the LMMSE limit.

Written from the equations of motion with numpy/scipy only; it imports nothing of railgsa_ros,
so that the project's coach model and inversion can be tested against it. Tests import it as
``reference`` (pytest puts test/ on sys.path); benchmarks insert test/ into sys.path (the repo
root is not enough: the standard library's regular package ``test`` would shadow test/).
"""
