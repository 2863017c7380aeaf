"""Training loops, one readable file per learner family (CleanRL style)."""
