"""Telerobot: drive a robot arm from a web browser, in stereo, with force feedback.

One package, split by where the code runs (docs/architecture.md):

- ``telerobot.server``: the server (``telerobot serve``; the repository's ``backend/``);
- ``telerobot.drivers``: robots, cameras, force sensors, master arms (``drivers/``);
- ``telerobot.calibration``: camera calibration and registration (``calibration/``);
- ``telerobot.protocol``: the wire protocol the server and its clients share;
- ``telerobot.client``: what runs on the operator's or a script's machine: the REST
  client (``from telerobot.client import Telerobot``) and the master-arm bridge.
"""
