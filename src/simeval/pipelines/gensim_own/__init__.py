"""GenSim's own code, run from the user's checkout (native.py, worker.py)."""
