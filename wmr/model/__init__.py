"""The nominal model: the unicycle's kinematics, the references and their waypoints, and its
symbolic (CasADi) form for exact Jacobians."""
