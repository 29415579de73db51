"""``ersac-hil reproduce``: the paper's experiments through the real stack.

    ersac-hil reproduce {bracing,lifting,contexts,all} [--seeds N] [--quick] [--out DIR] [--pairs N]

The same processes as ``ersac-hil demo`` (Zenoh router; per simulator/agent pair a simulator
and an agent, CAN over Zenoh; one ``ersac-hil daemon`` per learning run) on loopback, with a progress bar; every episode is in a
SQLite store in ``DIR`` (``runs/<run>.db`` per learning run, ``trials.db`` for independent
episodes), so an interrupted run resumes where it stopped. Writes figures (PNG),
``results.json`` and ``results.md`` into ``DIR``. Modules: ``plan`` (sizes, episodes),
``runner`` (pairs, daemons, trials, progress), ``trials`` (independent episodes and their
store), ``bracing`` / ``lifting`` / ``contexts`` (run + analyse), ``views`` (critic views of
the stores), ``stats`` (tests), ``figures``, ``results``, ``provenance`` (the code behind
the episodes and the learning runs), ``planfile`` (what ``plan.json`` records per experiment
and run, and what a new invocation may do with it), ``cli``.
"""
