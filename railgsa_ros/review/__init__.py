"""Offline review of a recorded run (no ROS import): ``railgsa review BAG --out DIR``.

``build.build_review`` runs the nodes' streaming core over the bag (``stream``) and analyses it:
isolated-defect exceedances of the EN 13848-5 limits (``exceedances``; the limits and the SD per
200 m are in ``railgsa_ros.standards``), input health (``health``), the surrogate at the worst
location (``worst``) and, with a truth, scores (``truth``); ``build.write_review`` draws the
PNGs (``figures``) and writes the HTML (``report``) atomically.
"""
