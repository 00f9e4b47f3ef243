"""The Telerobot Python client: ``from telerobot.client import Telerobot``."""
