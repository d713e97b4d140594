// The job specs of brenier.v1 to and from the typed requests of core/jobs (requests.hpp):
// the thin CLI builds a request from its flags and sends it as a spec, brenierd turns the
// spec it receives back into the same request. One translation each way, so that a spec
// means the same on both sides. The from_proto functions validate (Error(kInvalidArgument)
// naming the field); the mesh ids and the output format stay with the caller.
#pragma once

#include "brenier/v1/brenier.pb.h"
#include "jobs/requests.hpp"

namespace brenier::spec {

namespace pb = brenier::v1;

pb::Domain to_proto(jobs::Domain d);
pb::MapMethod to_proto(jobs::MapMethod m);
pb::DistanceMethod to_proto(distance::Method m);
jobs::Domain from_proto(pb::Domain d);
jobs::MapMethod from_proto(pb::MapMethod m);
distance::Method from_proto(pb::DistanceMethod m);

void to_proto(const jobs::MapRequest& r, pb::MapSpec* s);
void to_proto(const jobs::DistanceRequest& r, pb::DistanceSpec* s);
void to_proto(const jobs::MatrixRequest& r, pb::MatrixSpec* s);
void to_proto(const jobs::RegisterRequest& r, pb::RegisterSpec* s);

jobs::MapRequest from_proto(const pb::MapSpec& s);
jobs::DistanceRequest from_proto(const pb::DistanceSpec& s);
jobs::MatrixRequest from_proto(const pb::MatrixSpec& s);
jobs::RegisterRequest from_proto(const pb::RegisterSpec& s);

}  // namespace brenier::spec
