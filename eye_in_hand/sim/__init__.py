"""eye_in_hand.sim."""
