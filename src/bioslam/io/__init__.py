"""Readers and writers: everything that touches files lives here, outside the SLAM core."""
