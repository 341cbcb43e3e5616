"""The simulated robot: station, Diagram, Meshcat recording, disturbances and the closed-loop
run."""
