"""The muscle in MuJoCo: the actuator plugin, its Python engine, the rig and runs."""
