"""What varies an attempt's world beyond the task's own sampling: appearance randomisation and
small perturbations of the instance."""
