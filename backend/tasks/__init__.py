"""Supervisory tasks: a taught motion repeated by the server under the DecisionServer's
guards, with a compliance term from the force sensor."""
