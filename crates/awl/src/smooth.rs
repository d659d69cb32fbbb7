//! Moving-least-squares smoothing.
