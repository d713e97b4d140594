// Moebius normalizations of conformal maps (Thm 2.13 for the disk, sec. 3.2.5 for the
// sphere). Points of the plane are complex numbers.
#pragma once

#include <Eigen/Core>
#include <complex>

#include "mesh/mesh.hpp"

namespace brenier::conformal {

using Complex = std::complex<double>;

/// The disk automorphism z -> (z - a) / (1 - conj(a) z), |a| < 1: sends a to 0.
Complex disk_automorphism(Complex z, Complex a);

/// Applies z -> e^{i theta} (z - a) / (1 - conj(a) z) to every row of uv (#V by 2). When
/// `log_scale` (#V) is given, log |M'(z)| = log(1 - |a|^2) - 2 log |1 - conj(a) z| is added
/// to it per vertex, so a caller can follow the conformal factor through the map.
void apply_disk_mobius(mesh::UV& uv, Complex a, double theta, Eigen::VectorXd* log_scale = nullptr);

/// The disk automorphism that puts the centre of mass of the pushed-forward area at 0:
/// the area of face f (`face_area`, #F, of the original surface) sits at the image of the
/// face's centroid. Iterates a <- centroid, composing maps, until |centroid| <= tol.
/// Returns the number of iterations. `uv` is updated in place.
int center_disk(mesh::UV& uv, const mesh::Faces& F, const Eigen::VectorXd& face_area,
                double tol = 1e-12, int max_iterations = 200, Eigen::VectorXd* log_scale = nullptr);

/// The same for points on the unit sphere (#V by 3), with the mass of each vertex (a third
/// of its faces' areas) at the vertex, and the ball automorphism
/// x -> (1 - |a|^2)(x - a) / |x - a|^2 - a, which maps the sphere to itself and a to 0;
/// with `log_scale`, its stretch on the sphere, log((1 - |a|^2) / |x - a|^2), is added.
/// That ball automorphism on one point x of the unit sphere (|a| < 1), renormalized onto the
/// sphere against round-off. It is orientation preserving on the sphere.
Eigen::Vector3d sphere_automorphism(const Eigen::Vector3d& x, const Eigen::Vector3d& a);

int center_sphere(mesh::Vertices& X, const mesh::Faces& F, const Eigen::VectorXd& face_area,
                  double tol = 1e-12, int max_iterations = 200,
                  Eigen::VectorXd* log_scale = nullptr);

/// Stereographic projection from the north pole (0,0,1) to the plane and its inverse.
Complex stereographic(const Eigen::Vector3d& x);
Eigen::Vector3d inverse_stereographic(Complex z);

}  // namespace brenier::conformal
