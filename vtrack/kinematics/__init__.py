"""Hand kinematics: URDF forward kinematics, tactile sensor poses, fingertip IK (``vtrack.kinematics.ik``)."""
