"""Pure mechanics: rotations, the robot, kinematics (inverse, and forward: :mod:`.forward`), dynamics, control laws,
tension distribution, trajectories, cables and the workspace. numpy (and scipy, imported where a function needs
it) only: no I/O, no messaging, no files."""
