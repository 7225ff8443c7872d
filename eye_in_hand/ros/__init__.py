"""eye_in_hand.ros."""
