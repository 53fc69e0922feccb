"""Vehicle models that give the lateral acceleration from speed and steering."""
