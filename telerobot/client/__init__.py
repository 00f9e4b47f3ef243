"""What runs on the operator's or a script's machine, without the server: the REST
client (``Telerobot``, ``telerobot move``) and the master-arm bridge (``master``:
``telerobot master``; its clock sync is the protocol's, ``telerobot.protocol.clock``).
Importing it pulls in none of the server's dependencies (FastAPI, aiortc, Pinocchio):
tests/test_package.py."""

from telerobot.client.rest import DEFAULT_URL, Telerobot, TelerobotError, local_url, stored_token

__all__ = ["DEFAULT_URL", "Telerobot", "TelerobotError", "local_url", "stored_token"]
