"""Bench tools' core: the logic behind ``lupin check``, ``calibrate``, ``offsets`` and ``gains``.

Everything here is silent and async (STYLE rule 9): no ``print``, no ``input``,
no waiting for Enter. The CLI layer (``lupin/cli/``) asks the questions, draws
the tables and decides; these modules read and write the servos and files.

``session``        open the bus through the adapter registry, close it in a finally
``registers``      named register reads and writes; EEPROM writes with a double read-back
``health``         enumeration, per-servo health and the zero snapshot (``check``)
``sweep``          phase 1 of calibration: ranges recorded while the operator sweeps
``homing``         phase 2's arithmetic: offsets folded modulo 4096, bands, refusals
``offsets``        homing-offset backup, restore and the verified one-servo-at-a-time write
``overlay_file``   ``$LUPIN_HOME/arm.yaml``: built, validated, then saved atomically
``calibration``    phase 2 as a whole: prepare (no writes), then commit
``gains``          servo P/D/I against the profile: show and apply
``step_response``  scoring one gain trial, and the sweep's verdict (pure)
``gain_sweep``     running a gain sweep on one joint, with its guards
``lerobot``        LeRobot's per-motor calibration JSON, both ways
``files``          atomic writes
"""
