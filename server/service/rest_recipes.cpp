#include "service/rest_api.h"

// /api/recipes: the recipes the editor can record, and their recording jobs
// (service/recipe_jobs.h).
#include "service/recipe_jobs.h"
#include "service/rest_support.h"

namespace fc::service {

using namespace rest;

HttpResponse ServiceHub::listRecipes(const HttpRequest&, const Params&) {
  return jsonResponse(recipeJobs_->list([this](const std::string& name) { return database_.contains(name); }));
}

HttpResponse ServiceHub::startRecipeJob(const HttpRequest& req, const Params& p) {
  const json body = requireObject(parseBody(req, false));
  onlyKeys(body, {"force"});
  bool created = false;
  const JobInfo job = recipeJobs_->start(p[0], bodyBool(body, "force", false), created);
  HttpResponse r = jsonResponse(jobJson(job), created ? 202 : 200);
  r.headers.emplace_back("Location", "/api/recipes/jobs/" + job.id);
  return r;
}

HttpResponse ServiceHub::getRecipeJob(const HttpRequest&, const Params& p) {
  return jsonResponse(jobJson(recipeJobs_->job(p[0])));
}

HttpResponse ServiceHub::cancelRecipeJob(const HttpRequest&, const Params& p) {
  return jsonResponse(jobJson(recipeJobs_->cancel(p[0])));
}

}  // namespace fc::service
