"""kinematics package."""
