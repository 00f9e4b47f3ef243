"""The DecisionServer: one path for every motion command, whatever its source."""
