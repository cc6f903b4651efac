"""sensorsocket package."""
