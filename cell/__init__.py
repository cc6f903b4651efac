"""The emulated work cell: robot and sensor emulators and a seam scene on one clock."""
