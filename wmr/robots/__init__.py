"""The true robots a controller is judged on: the compiled plant effects (``plant``), the
``[plant]`` table (``plantspec``), the Python-level plant interface (``pyplant``) and the MuJoCo
differential drive."""
