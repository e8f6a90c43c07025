"""hexcal: calibrate Gough-Stewart platforms from leg-mobility constraints.

Units are millimetres, seconds and degrees Celsius throughout; quaternions in files are unit and
scalar first (``qw, qx, qy, qz``); every rotation goes through
:class:`scipy.spatial.transform.Rotation`.
"""

__version__ = "0.1.0"
