"""Units shared by the package. Imports nothing, so any module (the scene layer included) can
read it."""

#: Pa per mmHg (the conventional millimetre of mercury)
MMHG = 133.322387415
