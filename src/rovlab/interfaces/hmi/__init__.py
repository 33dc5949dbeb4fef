"""The HMI: a local web app to tune the model, the observer and the controller while a simulation
(or, through a bridge, the real vehicle) runs, and to watch the estimates live.

* :mod:`~rovlab.interfaces.hmi.source`: the Source protocol and SimulationSource
* :mod:`~rovlab.interfaces.hmi.documents`: the TOML parameter documents, edits and saving
* :mod:`~rovlab.interfaces.hmi.log`: the session log (CSV / MCAP)
* :mod:`~rovlab.interfaces.hmi.session`: the state and the commands (no web code)
* :mod:`~rovlab.interfaces.hmi.server`: the aiohttp app, WebSocket protocol and pacing
* ``static/``: the page (hand-written HTML, CSS and JavaScript, canvas plots)

Start it with ``rovlab hmi``. Only server.py needs aiohttp (the ``hmi`` extra).
"""
