"""Policies: what to indent next, as Decisions."""
