"""Offline review of a recorded run (no ROS import): ``railgsa review BAG --out DIR``.

``build.build_review`` runs the nodes' streaming core over the bag (``stream``) and analyses it:
EN 13848-5 limits (``limits``) and isolated-defect exceedances (``exceedances``), SD per 200 m
(``sections``), input health (``health``), the surrogate at the worst location (``worst``) and,
with a truth, scores (``truth``); ``build.write_review`` draws the PNGs (``figures``) and writes
the HTML (``report``) atomically.
"""
