"""The simulated character and stage on MuJoCo: bodies, PD tracking, virtual joints, posture database.

Never imports the bus; nodes call into it with arrays.
"""
