"""The Textual console only: the app, its widgets, the feed thread and the journal source."""
