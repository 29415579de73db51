"""Code the tests share, imported by name (``from helpers.waiting import wait_until``).

``tests/`` is on ``sys.path`` (``pythonpath`` in pyproject.toml); ``conftest.py`` files only
declare fixtures and are never imported.

* ``waiting``         - ``wait_until``: poll a condition up to a deadline, fail the test after it
* ``can_nodes``       - the reference nodes (static CiA 301 nodes from the EDS files), a test-side
                        CANopen master, a frame counter, the SDO barrier, actions at a SYNC
* ``cia402``          - the simulated CiA 402 robot with a stock ``BaseNode402`` master per drive
* ``plant``           - balancing the simulated plant without the agent (scenario tests)
* ``processes``       - end-to-end child processes: output up to a line, stopped, nothing left
* ``synthetic_agent`` - a stand-in for the robot-side agent with known costs (also a script)
* ``timing``          - patient agent and controller timing for tests that are not about it
* ``webclient``       - HTTP requests and a server-sent-events reader for the dashboard tests
"""
