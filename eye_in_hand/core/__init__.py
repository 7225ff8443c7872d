"""eye_in_hand.core."""
