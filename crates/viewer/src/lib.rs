//! pano4d-view: the 6-DoF viewer (issue 6 builds it here).
