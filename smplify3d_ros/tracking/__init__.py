"""People tracked across frames (`tracker.Tracker`): ids from the detector or from a gated association
(`association`), a constant-velocity filter per person (`motion`), one shape per person, warm starts."""
