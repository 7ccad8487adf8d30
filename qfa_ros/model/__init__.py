"""
The sensor model: the physics of the emulated QFA triad, in discrete time.

Hardware and its drift (Ran et al. 2019, eq. 1-13), controller design, the compiled per-step
loop kernel, noise, the thermal model, input profiles and the triad that runs them.
Everything here is SI units and explicit ``dt``. It may import numpy, scipy and numba
only: no other layer of ``qfa_ros``, no ROS, no file formats.
"""
