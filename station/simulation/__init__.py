"""Simulation: everything that needs the simulator or stands in for the world. Whole
simulated sessions scored against their truth, the simulated touching operator, trace
generators, Monte Carlo studies and ``app.py truth``. Nothing here is used by a real
station."""
