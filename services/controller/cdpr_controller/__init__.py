"""The controller service: feedback linearisation plus tension distribution, one command per state."""
