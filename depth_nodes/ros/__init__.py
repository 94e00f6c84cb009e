"""ROS glue: the only code that knows message layouts, parameters, QoS and synchronisation."""
