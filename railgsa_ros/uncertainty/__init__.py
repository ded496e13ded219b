"""Live uncertainty bands and window sensitivities of the reconstructed irregularity (no ROS).

``UncertaintyStream(config, vehicle, dists)`` runs the inverse for the rule's parameter points
as one bank and projects every sample on a PCE; ``offline_bands`` is the same code for a whole
recorded stream (``railgsa invert --bands``).
"""

from railgsa_ros.uncertainty.config import UncertaintyConfig, load_config
from railgsa_ros.uncertainty.stream import Band, UncertaintyStream, Update, offline_bands
from railgsa_ros.uncertainty.windows import Sensitivity

__all__ = ['Band', 'Sensitivity', 'UncertaintyConfig', 'UncertaintyStream', 'Update',
           'load_config', 'offline_bands']
