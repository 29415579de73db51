"""The live web dashboard (``ersac-hil dashboard``): a Zenoh client of the learner's control
plane serving one page with the learning curve, the critic, the state and the controls.

| module | job |
|---|---|
| ``model.py`` | pure: control-plane messages -> what the page shows (events, snapshot) |
| ``api.py`` | pure: JSON control bodies -> protocol commands (the protocol's validation); errors -> HTTP |
| ``bridge.py`` | Zenoh: subscriptions, state/critic refresher, blocking controls |
| ``server.py`` | Starlette app (page, static files, JSON API, server-sent events) on uvicorn |
| ``cli.py`` | the ``dashboard`` subcommand |
| ``static/`` | the page: HTML, CSS, JavaScript (Plotly.js from the ``plotly`` package) |

See ``docs/dashboard.md``.
"""
