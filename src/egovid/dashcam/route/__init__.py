"""Where and when a drive was: GPS tracks (files and embedded), clocks, trips of loop files, and
the path catalogue's matching (thesis §14.1, §15.1)."""
