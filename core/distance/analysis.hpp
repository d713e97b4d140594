// What researchers do with a distance matrix (dissertation sec. 4.4.2-4.4.3): embed it
// (classical multidimensional scaling) and classify by nearest neighbours.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

namespace brenier::distance {

struct Embedding {
  Eigen::MatrixXd coordinates;     // n x dims
  Eigen::VectorXd eigenvalues;     // of the doubly centred -D^2/2, the kept ones first, descending
  double captured = 0;             // share of the positive eigenvalues' sum the kept ones hold
  double negative = 0;             // |sum of negative eigenvalues| / sum of |eigenvalues| (0 for Euclidean D)
};

/// Classical (Torgerson) MDS: B = -J D^2 J / 2 with J = I - 11^T/n; coordinates are the top
/// `dims` eigenvectors scaled by the square roots of their eigenvalues (0 where negative).
Embedding classical_mds(const Eigen::MatrixXd& d, int dims);

struct KnnResult {
  int k = 1;
  int folds = 0;  // 0: leave-one-out
  int correct = 0, total = 0;
  double accuracy = 0;
  std::vector<std::string> predicted;  // per shape
};

/// k-nearest-neighbour classification from the distances: each shape gets the majority label
/// of its k nearest among the shapes it may see (all others for leave-one-out; with
/// `folds` > 1, the shapes outside its fold, shape i being in fold i mod folds). A tie of
/// votes goes to the tied label with the nearest member. Throws Error(kInvalidArgument) for
/// k < 1, folds of 1 or more than n, or a shape with no label.
KnnResult knn_classify(const Eigen::MatrixXd& d, const std::vector<std::string>& labels, int k, int folds);

}  // namespace brenier::distance
