"""The daemon: live run, systemd notify / watchdog, metrics."""
