"""Estimation: the pose and weight EKFs (``ekf``), the identifier network (``nn``), the quality of
an identified Jacobian (``identification``), the DEKF's boundedness constants (``stability``) and
``wmr identify`` (a ``[plant]`` fitted to a robot's log)."""
