"""ROS 2 glue of elastic_pm_dyn (message types, nodes); needs a ROS 2 Jazzy install."""
