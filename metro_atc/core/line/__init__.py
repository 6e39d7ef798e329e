"""Static line description: scenario, rolling stock, track grids, timetable, adhesion."""
