"""DBC loading and the frame decoder: frames to current / effort samples."""
