"""The physics proving ground: a simulated grasp trial and the contenders it judges (issue 36)."""
