"""Telerobot for LeRobot: the arm behind a server as a LeRobot robot (``arm``), the
operator at it as a LeRobot teleoperator (``operator``), both in LeRobot's units
(``units``, shared with the server's LeRobot export). The plugins that LeRobot's tools
load are thin wrappers of these, in ``integrations/lerobot/`` (docs/lerobot.md); this
package needs no LeRobot, so it is tested with this project's own tests."""
