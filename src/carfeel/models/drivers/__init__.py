"""Driver models: pure steps that produce the force a hand applies to a control."""
