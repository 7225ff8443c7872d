"""eye_in_hand.io."""
