"""URDF models shipped with multibody (installed as ``multibody.robot_files``; see ``multibody.robots``)."""
