"""The KLA iMicro driver: InView export reader and file exchange."""
