"""Servo and motor buses shared by the arms built of them (one folder per maker)."""
