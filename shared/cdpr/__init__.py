"""cdpr: the common library of the cable-driven parallel robot simulator.

Pure math (kinematics, dynamics, tension distribution, trajectories, control laws), the robot and
scenario file loaders, and the wire protocol shared by every service. Nothing here does I/O except
the loaders and the transport helpers, which say so in their names.
"""

__version__ = "0.1.0"
