"""The HTTP front cache: nginx keeping versioned tiles on disk in front of the app."""
