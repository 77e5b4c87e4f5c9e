"""AE-NI console: the CLI and the Textual operator console."""
