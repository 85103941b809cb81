"""Running generated filters the way firmware does: scenarios, log readers, harnesses."""
