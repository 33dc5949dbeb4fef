"""The vehicle node: a middleware-free core (:mod:`.core`) and its adapters (ROS 2, ROS 1), which
import their middleware lazily, only when run."""
