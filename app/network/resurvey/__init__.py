"""Re-survey: match new roads (a new extraction, a new file) against a stored network and
propose the changes as a change set that people review (issue 36)."""
