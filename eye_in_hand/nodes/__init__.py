"""eye_in_hand.nodes."""
