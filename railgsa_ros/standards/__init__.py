"""Railway standards the review and the fleet apply alike (no ROS, nothing of review or fleet).

``en13848``: the EN 13848 wavelength bands and the EN 13848-5 isolated-defect limits (the
standard's table, a manager's table from YAML, ``classify``); ``line_speed``: the line's
permitted speed per km range; ``sampling``: the 0.25 m distance grid; ``sections``: the SD per
200 m section.
"""
