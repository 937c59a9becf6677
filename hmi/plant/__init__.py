"""Plants: the contract (base.py), simulated plants (sim/), real ones over Modbus (modbus/)."""
