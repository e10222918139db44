#include "core/pipeline/finish_flight.h"

#include "core/pipeline/end_of_flight.h"

namespace uavm {

bool FinishFlight(FlightSession* session, LiveView* live, OutputAdditions additions, FlightSummary* summary,
                  std::string* error) {
  session->EndFlight();
  if (live != nullptr) live->StopForFinalTiles();
  const Solution solution = session->Solve();
  if (!solution.ok) {
    *error = solution.failure;
    return false;
  }
  summary->registered = static_cast<int>(solution.component.size());
  summary->residual_rms_px = solution.rms_px;
  EndOfFlight::Inputs inputs;
  inputs.record = &session->record();
  inputs.solution = &solution;
  inputs.lens = &session->lens();
  inputs.session = session;
  inputs.live = live;
  inputs.additions = std::move(additions);
  EndOfFlight end(session->options(), session->paths(), std::move(inputs));
  if (!end.Run(error)) return false;
  session->MarkFinished();
  return true;
}

}  // namespace uavm
