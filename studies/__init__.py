"""Studies of measured data sets with the package (not part of the installed package)."""
