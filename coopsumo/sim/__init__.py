"""The simulation: the road network, the one SUMO session, pure array physics, observations, rewards,
and the world that steps them. Imports nothing from agents, studies or report."""
