"""The data model below everything: geometry, schedule, exposure, flags, errors."""
