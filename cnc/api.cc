#include "cnc/api.h"

namespace formloop::cnc {

namespace {

Result<ApiResponse> Answered(Result<ApiResponse> answer) {
  if (!answer.ok()) return answer.status();
  if (!answer->ok) return Status::Failed(answer->error);
  return answer;
}

}  // namespace

Result<std::vector<MacroValue>> RequestTransport::ReadRange(int start, int count) {
  ApiRequest r;
  r.op = ApiRequest::Op::kReadRange;
  r.start = start;
  r.count = count;
  FL_ASSIGN_OR_RETURN(ApiResponse a, Answered(Call(r)));
  if (static_cast<int>(a.values.size()) != count)
    return Status::IoError("the controller answered with the wrong number of values");
  return std::move(a.values);
}

Status RequestTransport::WriteRange(int start, const std::vector<double>& values) {
  ApiRequest r;
  r.op = ApiRequest::Op::kWriteRange;
  r.start = start;
  r.values = values;
  return Answered(Call(r)).status();
}

Result<double> RequestTransport::ReadOffset(const OffsetAddress& offset) {
  ApiRequest r;
  r.op = ApiRequest::Op::kReadOffset;
  r.offset = offset.ToString();
  FL_ASSIGN_OR_RETURN(ApiResponse a, Answered(Call(r)));
  return a.value;
}

Status RequestTransport::WriteOffset(const OffsetAddress& offset, double value_mm) {
  ApiRequest r;
  r.op = ApiRequest::Op::kWriteOffset;
  r.offset = offset.ToString();
  r.value = value_mm;
  return Answered(Call(r)).status();
}

}  // namespace formloop::cnc
