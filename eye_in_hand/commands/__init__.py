"""eye_in_hand.commands."""
